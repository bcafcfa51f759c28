"""A foreign arm's action space for the adapter tests: its own joint order, degrees, millimetres,
a flipped elbow. The conversion is written out by hand, independent of the ActionMap it tests."""

import numpy as np

from cellguard.policy.scripted_arm import ScriptedArmPolicy
from cellguard.robot.arm_cell import ArmPickPlace
from cellguard.robot.state import Observation

# Profile order is pan, lift, elbow, flex, roll, gripper; the foreign robot lists them reversed.
FOREIGN_ORDER = [5, 4, 3, 2, 1, 0]
FOREIGN_NAMES = ["gripper.mm", "wrist_roll.deg", "wrist_flex.deg", "elbow.deg", "shoulder_lift.deg", "shoulder_pan.deg"]
FOREIGN_SIGN = np.array([1, 1, 1, -1, 1, 1.0])
FOREIGN_SCALE = np.array([1e3, *[180.0 / np.pi] * 5])  # SI -> foreign units, foreign order
MAP = {"robot": "arm-pick-place", "actions": [
    {"name": "gripper.mm", "joint": "gripper", "unit": "mm"},
    {"name": "wrist_roll.deg", "joint": "wrist_roll", "unit": "deg"},
    {"name": "wrist_flex.deg", "joint": "wrist_flex", "unit": "deg"},
    {"name": "elbow.deg", "joint": "elbow", "unit": "deg", "sign": -1},
    {"name": "shoulder_lift.deg", "joint": "shoulder_lift", "unit": "deg"},
    {"name": "shoulder_pan.deg", "joint": "shoulder_pan", "unit": "deg"}]}


def to_foreign(q: np.ndarray) -> np.ndarray:
    return np.asarray(q)[..., FOREIGN_ORDER] * FOREIGN_SCALE * FOREIGN_SIGN


def from_foreign(v: np.ndarray) -> np.ndarray:
    q = np.empty(6)
    q[FOREIGN_ORDER] = np.asarray(v) / (FOREIGN_SCALE * FOREIGN_SIGN)
    return q


def taught_program(period_s: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """The scripted arm program sampled every ``period_s``: times (N,) [s], joint targets (N, 6)."""
    cell = ArmPickPlace(seed=1)
    cell.begin_cycle(0)
    obs = cell.observe()
    policy = ScriptedArmPolicy(horizon=1, calibration=cell.context())
    times = np.arange(0.0, 4.6, period_s)
    points = [policy.infer(Observation(round(t * 1e9) - policy.dt_ns, obs.q, obs.qd, obs.measurements)).actions[0]
              for t in times]
    return times, np.array(points)


def assert_ran_inside_the_limits(run, outcomes: list[dict]) -> None:
    """A policy run through the whole tick path: every cycle succeeded with its chunks timed, every
    setpoint inside the profile's position limits, no chunk refused."""
    assert all(o["success"] for o in outcomes), outcomes
    assert all(o["inference"]["chunks"] > 10 and o["inference"]["wall_ms_max"] > 0 for o in outcomes)
    assert (run.ticks.rows("setpoint") >= run.cell.profile.q_min).all()
    assert (run.ticks.rows("setpoint") <= run.cell.profile.q_max).all()
    assert not any(e.kind == "chunk_rejected" for e in run.events)
