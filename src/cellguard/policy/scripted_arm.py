"""A taught pick-and-place program for the pick-place cells, emitted as action chunks.

It behaves like a vision-guided taught program: joint waypoints taught once by IK on the
nominal model, and a pick pose corrected by what the camera sees, within ``VISION_RANGE``
(real cells allow a few millimetres). Small drift is absorbed and shows only in the record;
a large fixture shift or a knocked camera makes grasps fail. It knows nothing of faults.
What differs between arms (model, joints the IK moves, gripper values, tempo) is a ``Teaching``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numpy as np

from cellguard.policy.chunk import ActionChunk
from cellguard.policy.protocol import Policy, behaviour_hash
from cellguard.robot import arm_cell, so101_cell
from cellguard.robot.kinematics import solve_tool_down
from cellguard.robot.pick_place import CAMERA_ROTATION
from cellguard.robot.state import Observation

VISION_RANGE = 0.003  # [m] largest correction of the taught pick position


@dataclass(frozen=True)
class Teaching:
    """How a program is taught on one arm; gripper values in the gripper joint's unit ([m] or [rad])."""

    load_model: Callable[[], mujoco.MjModel]  # the nominal model the poses are taught on
    arm: tuple[str, ...]  # joints the IK moves; the joint after them (wrist roll) stays at home
    home: tuple[float, ...]  # (dof,) profile order, gripper open
    gripper_open: float
    gripper_shut: float
    part_half: float  # [m]
    approach: float = 0.08  # [m] height of the approach poses above pick and place
    tempo: float = 1.0  # waypoint times are multiplied by this


ARM = Teaching(arm_cell.load_model, ("shoulder_pan", "shoulder_lift", "elbow", "wrist_flex"),
               arm_cell.LAYOUT.q_home, gripper_open=0.025, gripper_shut=0.008, part_half=arm_cell.PART_HALF)
# The SO-101's jaw travels 0.35 rad and its wrist roll joins the IK (its axis sits 2 deg off the arm's plane);
# tempo 1.3 keeps the program inside the STS3215 profile.
SO101 = Teaching(so101_cell.load_model, ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll"),
                 so101_cell.LAYOUT.q_home, gripper_open=0.55, gripper_shut=0.2, part_half=so101_cell.PART_HALF,
                 approach=0.05, tempo=1.3)
# The program's waypoints: (time [s] at tempo 1, pose, gripper): pose is home, above, pick, above_drop or drop.
PROGRAM = ((0.8, "above", "open"), (1.2, "pick", "open"), (1.4, "pick", "open"), (1.65, "pick", "shut"),
           (2.05, "above", "shut"), (2.85, "above_drop", "shut"), (3.25, "drop", "shut"), (3.45, "drop", "open"),
           (3.75, "above_drop", "open"), (4.45, "home", "open"))


def _min_jerk(u: np.ndarray) -> np.ndarray:
    return u * u * u * (10.0 - 15.0 * u + 6.0 * u * u)


class ScriptedArmPolicy(Policy):
    """Emits ``horizon`` steps of ``dt`` seconds along the taught program, from the observation."""

    source = "scripted"

    def __init__(self, horizon: int = 25, dt: float = 0.02, calibration: dict | None = None,
                 teaching: Teaching = ARM, vision_range: float = VISION_RANGE):
        self.horizon, self.dt_ns, self.teaching = horizon, round(dt * 1e9), teaching
        self.vision_range = float(vision_range)
        self._model = m = teaching.load_model()
        data = mujoco.MjData(m)
        mujoco.mj_forward(m, data)

        def mocap(body: str) -> np.ndarray:
            return data.mocap_pos[m.body_mocapid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, body)]].copy()

        def site(name: str) -> np.ndarray:
            return data.site_xpos[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, name)].copy()

        fixture = mocap("fixture") if calibration is None else np.asarray(calibration["fixture_datum"])
        datum_above_fixture = site("fixture_datum") - mocap("fixture")
        self.taught_part = (np.asarray(fixture, dtype=np.float64) + datum_above_fixture
                            + np.array([0.0, 0.0, teaching.part_half]))
        cam = calibration["camera_calibration"] if calibration else None
        self._cam_pos = np.asarray(cam["position"]) if cam else mocap("camera_mount")
        self._cam_rot = np.asarray(cam["rotation"]) if cam else CAMERA_ROTATION
        self.home = np.array(teaching.home, dtype=np.float64)
        drop = site("drop_zone")
        drop[2] = teaching.part_half + 0.002
        self._drop_q = self._ik(drop)
        self._above_drop_q = self._ik(drop + [0.0, 0.0, teaching.approach])
        self._program: list[tuple[float, np.ndarray]] | None = None
        self._t0_ns: int | None = None
        self.correction = np.zeros(3)

    def reset(self) -> None:
        self._program, self._t0_ns = None, None

    def content_hash(self) -> str:
        t, m = self.teaching, self._model
        return behaviour_hash(self, self.horizon, self.dt_ns, self.vision_range, self.taught_part, self._cam_pos,
                              self._cam_rot, self.home, self._drop_q, self._above_drop_q, t.arm, t.home,
                              t.gripper_open, t.gripper_shut, t.part_half, t.approach, t.tempo,
                              m.body_pos, m.body_quat, m.site_pos, m.jnt_range)

    def infer(self, observation: Observation) -> ActionChunk:
        if self._program is None:
            self._t0_ns = observation.t_ns
            self._program = self._plan(observation)
        t = (observation.t_ns - self._t0_ns + (np.arange(self.horizon) + 1) * self.dt_ns) * 1e-9
        return ActionChunk(actions=self._at(t), t_obs_ns=observation.t_ns, dt_ns=self.dt_ns)

    def _plan(self, obs: Observation) -> list[tuple[float, np.ndarray]]:
        """The cycle's waypoints (end time [s], joint targets), pick corrected by vision."""
        seen = self._cam_rot @ obs.measurements["part_in_camera"] + self._cam_pos
        delta = seen - self.taught_part
        delta[2] = 0.0
        norm = float(np.linalg.norm(delta))
        self.correction = delta if norm <= self.vision_range else delta * (self.vision_range / norm)
        t = self.teaching
        poses = {"home": self.home[:len(t.arm)], "pick": self._ik(self.taught_part + self.correction),
                 "above": self._ik(self.taught_part + self.correction + [0.0, 0.0, t.approach]),
                 "drop": self._drop_q, "above_drop": self._above_drop_q}
        grip = {"open": t.gripper_open, "shut": t.gripper_shut}
        roll = self.home[len(t.arm):-1]  # the wrist roll stays as at home
        return [(0.0, self.home)] + [(time * t.tempo, np.concatenate([poses[pose], roll, [grip[g]]]))
                                     for time, pose, g in PROGRAM]

    def _at(self, t: np.ndarray) -> np.ndarray:
        times = np.array([w[0] for w in self._program])
        poses = np.array([w[1] for w in self._program])
        k = np.clip(np.searchsorted(times, t, side="right"), 1, len(times) - 1)
        u = np.clip((t - times[k - 1]) / (times[k] - times[k - 1]), 0.0, 1.0)
        s = _min_jerk(u)[:, None]
        return poses[k - 1] + s * (poses[k] - poses[k - 1])

    def _ik(self, target: np.ndarray) -> np.ndarray:
        arm = self.teaching.arm
        return solve_tool_down(self._model, "tcp", list(arm), np.asarray(target, dtype=np.float64),
                               self.home[:len(arm)])
