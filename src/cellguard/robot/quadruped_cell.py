"""The quadruped-turns cell: a 12-joint quadruped walking alternate left and right turns.

One cycle is one turn: for ``TURN_S`` the cell commands ``SPEED`` forward and ``YAW_RATE``
(left on even cycles, right on odd ones), then zero, and the cycle ends once the robot stands
still. The body yaw rate is measured over the steady part of the turn (``STEADY_FROM_S`` to
``TURN_S``, whole gait periods) from the unwrapped heading; the foot touch sensors give each
leg's contact duty and touchdown timing over the same window. A fallen robot is set back on
its feet at the start of the next cycle, as a technician would.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from cellguard.embodiment import load_profile
from cellguard.robot.drives import DrivenCell, PositionDrives
from cellguard.robot.protocol import SafetyInputs
from cellguard.robot.state import Observation

ASSETS = Path(__file__).parent / "assets"
LEGS = ("fl", "fr", "rl", "rr")
DIAGONAL = {"fl": "rr", "fr": "rl", "rl": "fr", "rr": "fl"}
SPEED = 0.25  # [m/s] commanded forward speed during a turn
YAW_RATE = 0.6  # [rad/s] commanded yaw rate magnitude
TURN_S = 3.0  # [s] how long a turn is commanded
STEADY_FROM_S = 1.0  # [s] the steady window of a turn starts here and ends at TURN_S
YAW_TOLERANCE = 0.15  # a turn succeeds when |reached / commanded - 1| is within this
SAMPLE_TICKS = 10  # body pose sampled every this many servo ticks of a cycle
CONTACT_FORCE = 1.0  # [N] foot touch force above which the foot is down
MIN_SWING_S = 0.05  # [s] a foot must have been up this long for its landing to count as a touchdown
FALLEN_HEIGHT = 0.15  # [m] torso height below which the robot has fallen
FALLEN_UPRIGHT = 0.5  # cosine of torso tilt below which the robot has fallen
SETTLED_SPEED = 0.2  # [rad/s] every joint slower than this: the robot stands still
SETTLE_MIN_S = 0.3  # [s] a cycle lasts at least this long after the command ends
CURRENT_NOISE = 0.01  # [A] 1-sigma noise of each motor current reading
BRAKE_DAMPING = 5.0  # [N·m·s/rad] joint damping with power off: the robot sits down, it does not drop


def _yaw(quat: np.ndarray) -> float:
    w, x, y, z = quat
    return float(np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))


class QuadrupedTurns(DrivenCell):
    """A simulated quadruped at a 1 ms servo period. Joint order is the profile's."""

    name = "quadruped-turns"
    supported_faults = frozenset({"friction_growth", "friction_step", "servo_gain", "policy_latency", "policy_nan"})

    @staticmethod
    def mjcf_spec() -> mujoco.MjSpec:
        """The commissioned MJCF as an editable spec (``identify --write`` writes a calibrated copy)."""
        return mujoco.MjSpec.from_file(str(ASSETS / "quadruped.xml"))

    def __init__(self, seed: int = 0):
        self.model = mujoco.MjModel.from_xml_path(str(ASSETS / "quadruped.xml"))
        self.data = mujoco.MjData(self.model)
        self.profile = load_profile(self.model, ASSETS / "quadruped_profile.yaml")
        self.dt_ns = round(self.model.opt.timestep * 1e9)
        self.rng = np.random.default_rng(seed)
        self.drives = PositionDrives(self.model, self.data, self.profile, self.rng, CURRENT_NOISE, BRAKE_DAMPING)
        self.safety_inputs = SafetyInputs()  # the simulated safety controller's outputs; set by scenario or test
        m = self.model
        self._stand = m.key("stand")
        self._torso = m.body("torso").id
        self._root_q = m.jnt_qposadr[m.joint("root").id]
        touch = [m.sensor(f"{leg}_touch") for leg in LEGS]
        self._touch = np.array([m.sensor_adr[s.id] for s in touch])
        self._diagonal = np.array([LEGS.index(DIAGONAL[leg]) for leg in LEGS])
        mujoco.mj_resetDataKeyframe(m, self.data, self._stand.id)
        mujoco.mj_forward(m, self.data)
        self._command = np.zeros(2)  # (speed [m/s], yaw rate [rad/s])
        self._cycle_start_ns = 0
        self._begin_cycle_state()

    def _begin_cycle_state(self) -> None:
        self._ticks = 0  # servo ticks since the cycle began
        self._heading = _yaw(self.data.qpos[self._root_q + 3:self._root_q + 7])
        self._turned = 0.0  # [rad] unwrapped heading change since the cycle began
        self._xy = self.data.qpos[self._root_q:self._root_q + 2].copy()
        self._window: dict[str, float] = {}  # heading and forward distance at the window's ends
        self._forward = 0.0  # [m] distance along the heading since the cycle began
        self._samples: list[tuple[float, float, float]] = []  # (roll, pitch, height) in the window
        self._contact_ticks = np.zeros(4)
        self._window_ticks = 0
        self._down = self.data.sensordata[self._touch] > CONTACT_FORCE
        self._lifted = np.full(4, np.inf)  # [s] when each foot last left the ground in the window
        self._touchdowns: list[list[float]] = [[] for _ in LEGS]
        self._fallen = False

    # -- Robot -------------------------------------------------------------------------
    def step(self) -> None:
        self.physics_step()
        self._ticks += 1
        elapsed = self.data.time - self._cycle_start_ns * 1e-9
        in_window = STEADY_FROM_S <= elapsed < TURN_S
        if in_window:
            self._track_feet(elapsed)
        if self._ticks % SAMPLE_TICKS == 0:
            self._sample_body(elapsed, in_window)

    def _track_feet(self, elapsed: float) -> None:
        down = self.data.sensordata[self._touch] > CONTACT_FORCE
        self._contact_ticks += down
        self._window_ticks += 1
        changed = down != self._down
        if changed.any():
            for i in np.flatnonzero(changed):
                if not down[i]:
                    self._lifted[i] = elapsed
                elif elapsed - self._lifted[i] >= MIN_SWING_S:
                    self._touchdowns[i].append(elapsed)
            self._down = down

    def _sample_body(self, elapsed: float, in_window: bool) -> None:
        d = self.data
        qpos = d.qpos[self._root_q:self._root_q + 7]
        heading = _yaw(qpos[3:7])
        step = qpos[:2] - self._xy
        self._forward += float(step[0] * np.cos(heading) + step[1] * np.sin(heading))
        self._xy = qpos[:2].copy()
        self._turned += (heading - self._heading + np.pi) % (2.0 * np.pi) - np.pi
        self._heading = heading
        if in_window:
            xmat = d.xmat[self._torso]
            self._samples.append((float(np.arctan2(xmat[7], xmat[8])), float(-np.arcsin(xmat[6])), float(qpos[2])))
            self._window.setdefault("turned_from", self._turned)
            self._window.setdefault("forward_from", self._forward)
            self._window.setdefault("from_s", elapsed)
            self._window.update(turned_to=self._turned, forward_to=self._forward, to_s=elapsed)
        self._fallen = self._fallen or bool(qpos[2] < FALLEN_HEIGHT or d.xmat[self._torso, 8] < FALLEN_UPRIGHT)

    # -- Task ------------------------------------------------------------------------
    def observe(self) -> Observation:
        on = self.data.time - self._cycle_start_ns * 1e-9 < TURN_S
        return Observation(
            t_ns=self.t_ns,
            q=self.data.qpos[self.drives.qadr].copy(),
            qd=self.data.qvel[self.drives.dadr].copy(),
            measurements={
                "speed_command": np.array([self._command[0] * on]),
                "yaw_rate_command": np.array([self._command[1] * on]),
            },
        )

    def begin_cycle(self, cycle: int) -> None:
        if self._fallen:
            self._stand_up()
        self._command = np.array([SPEED, YAW_RATE if cycle % 2 == 0 else -YAW_RATE])
        self._cycle_start_ns = self.t_ns
        self._begin_cycle_state()

    def _stand_up(self) -> None:
        """Set the robot back on its feet in the stance, where it lies, facing where it faces."""
        d = self.data
        xy, heading = d.qpos[self._root_q:self._root_q + 2].copy(), _yaw(d.qpos[self._root_q + 3:self._root_q + 7])
        time = d.time
        mujoco.mj_resetDataKeyframe(self.model, d, self._stand.id)
        d.time = time
        d.qpos[self._root_q:self._root_q + 2] = xy
        d.qpos[self._root_q + 3:self._root_q + 7] = [np.cos(heading / 2), 0.0, 0.0, np.sin(heading / 2)]
        mujoco.mj_forward(self.model, d)

    def cycle_under_way(self) -> bool:
        """A turn is walked from the moment it is commanded."""
        return True

    def cycle_finished(self) -> bool:
        if self._fallen:
            return True
        if self.data.time - self._cycle_start_ns * 1e-9 < TURN_S + SETTLE_MIN_S:
            return False
        still = np.abs(self.data.qvel[self.drives.dadr]).max() < SETTLED_SPEED
        return bool(still and (self.data.sensordata[self._touch] > CONTACT_FORCE).all())

    def end_cycle(self) -> dict:
        speed, yaw_rate = self._command
        w = self._window
        span = w["to_s"] - w["from_s"] if w else 0.0
        reached = (w["turned_to"] - w["turned_from"]) / span if span > 0 else 0.0
        forward = (w["forward_to"] - w["forward_from"]) / span if span > 0 else 0.0
        ratio = reached / yaw_rate
        outcome = {
            "success": bool(not self._fallen and abs(ratio - 1.0) <= YAW_TOLERANCE),
            "cycle_time_s": (self.t_ns - self._cycle_start_ns) * 1e-9,
            "direction": "left" if yaw_rate > 0 else "right",
            "fallen": self._fallen,
            "yaw_rate_command": float(yaw_rate),
            "yaw_rate_reached": float(reached),
            "yaw_rate_ratio": float(ratio),
            "heading_change_rad": float(self._turned),
            "speed_command": float(speed),
            "speed_reached": float(forward),
        }
        if self._samples:
            roll, pitch, height = np.mean(self._samples, axis=0)
            outcome.update(body_roll_rad=float(roll), body_pitch_rad=float(pitch), body_height_m=float(height))
        outcome.update(self._gait_timing())
        return outcome

    def _gait_timing(self) -> dict[str, float]:
        """Per leg over the steady window: contact duty, step period, touchdown lag behind its diagonal."""
        out: dict[str, float] = {}
        for i, leg in enumerate(LEGS):
            mine, partner = np.array(self._touchdowns[i]), np.array(self._touchdowns[self._diagonal[i]])
            out[f"contact_duty.{leg}"] = float(self._contact_ticks[i] / max(self._window_ticks, 1))
            out[f"step_period_s.{leg}"] = float(np.diff(mine).mean()) if len(mine) > 1 else 0.0
            if len(mine) and len(partner):
                nearest = partner[np.abs(mine[:, None] - partner[None, :]).argmin(axis=1)]
                out[f"touchdown_lag_s.{leg}"] = float(np.mean(mine - nearest))
            else:
                out[f"touchdown_lag_s.{leg}"] = 0.0
        return out

    def context(self) -> dict:
        return {
            "cell": self.name,
            "turn_command": {"speed_m_s": SPEED, "yaw_rate_rad_s": YAW_RATE, "duration_s": TURN_S},
            "steady_window_s": [STEADY_FROM_S, TURN_S],
        }
