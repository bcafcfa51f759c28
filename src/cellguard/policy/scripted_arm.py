"""A taught pick-and-place program for the arm cell, emitted as action chunks.

It behaves like a vision-guided taught program: joint waypoints taught once by IK on the
nominal model, and a pick pose corrected by what the camera sees, within ``VISION_RANGE``
(real cells allow a few millimetres). Small drift is absorbed and shows only in the record;
a large fixture shift or a knocked camera makes grasps fail. It knows nothing of faults.
"""

from __future__ import annotations

import mujoco
import numpy as np

from cellguard.policy.chunk import ActionChunk
from cellguard.policy.protocol import Policy, behaviour_hash
from cellguard.robot.arm_cell import ASSETS, CAMERA_ROTATION, PART_HALF
from cellguard.robot.kinematics import solve_tool_down
from cellguard.robot.state import Observation

VISION_RANGE = 0.003  # [m] largest correction of the taught pick position
GRIPPER_OPEN, GRIPPER_SHUT = 0.025, 0.008  # [m] finger opening targets
APPROACH = 0.08  # [m] height of the approach poses above pick and place
ARM = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_flex"]


def _min_jerk(u: np.ndarray) -> np.ndarray:
    return u * u * u * (10.0 - 15.0 * u + 6.0 * u * u)


class ScriptedArmPolicy(Policy):
    """Emits ``horizon`` steps of ``dt`` seconds along the taught program, from the observation.

    ``vision_range`` [m]: the largest correction of the taught pick position the camera may make;
    ``calibration``: the cell's fixture datum and camera calibration (default: the nominal model's).
    """

    source = "scripted"

    def __init__(self, horizon: int = 25, dt: float = 0.02, calibration: dict | None = None,
                 vision_range: float = VISION_RANGE):
        self.horizon, self.dt_ns, self.vision_range = horizon, round(dt * 1e9), float(vision_range)
        self._model = mujoco.MjModel.from_xml_path(str(ASSETS / "arm.xml"))
        data = mujoco.MjData(self._model)
        fixture = data.mocap_pos[0] if calibration is None else np.asarray(calibration["fixture_datum"])
        self.taught_part = np.asarray(fixture, dtype=np.float64) + np.array([0.0, 0.0, 0.006 + PART_HALF])
        cam = calibration["camera_calibration"] if calibration else None
        self._cam_pos = np.asarray(cam["position"]) if cam else data.mocap_pos[1].copy()
        self._cam_rot = np.asarray(cam["rotation"]) if cam else CAMERA_ROTATION
        self.home = np.array([0.0, -0.3, 1.9, 1.55, 0.0, GRIPPER_OPEN])
        mujoco.mj_forward(self._model, data)
        drop = data.site_xpos[mujoco.mj_name2id(self._model, mujoco.mjtObj.mjOBJ_SITE, "drop_zone")].copy()
        drop[2] = PART_HALF + 0.002
        self._drop_q = self._ik(drop)
        self._above_drop_q = self._ik(drop + [0.0, 0.0, APPROACH])
        self._program: list[tuple[float, np.ndarray]] | None = None
        self._t0_ns: int | None = None
        self.correction = np.zeros(3)

    def reset(self) -> None:
        self._program, self._t0_ns = None, None

    def content_hash(self) -> str:
        return behaviour_hash(self, self.horizon, self.dt_ns, self.vision_range, self.taught_part, self._cam_pos,
                              self._cam_rot, self.home, self._drop_q, self._above_drop_q,
                              (ASSETS / "arm.xml").read_bytes())

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
        pick = self._ik(self.taught_part + self.correction)
        above = self._ik(self.taught_part + self.correction + [0.0, 0.0, APPROACH])

        def grip(q: np.ndarray, g: float) -> np.ndarray:
            return np.append(q, [0.0, g])

        o, s = GRIPPER_OPEN, GRIPPER_SHUT
        return [
            (0.0, self.home),
            (0.8, grip(above, o)),
            (1.2, grip(pick, o)),
            (1.4, grip(pick, o)),
            (1.65, grip(pick, s)),
            (2.05, grip(above, s)),
            (2.85, grip(self._above_drop_q, s)),
            (3.25, grip(self._drop_q, s)),
            (3.45, grip(self._drop_q, o)),
            (3.75, grip(self._above_drop_q, o)),
            (4.45, self.home),
        ]

    def _at(self, t: np.ndarray) -> np.ndarray:
        times = np.array([w[0] for w in self._program])
        poses = np.array([w[1] for w in self._program])
        k = np.clip(np.searchsorted(times, t, side="right"), 1, len(times) - 1)
        u = np.clip((t - times[k - 1]) / (times[k] - times[k - 1]), 0.0, 1.0)
        s = _min_jerk(u)[:, None]
        return poses[k - 1] + s * (poses[k] - poses[k - 1])

    def _ik(self, target: np.ndarray) -> np.ndarray:
        return solve_tool_down(self._model, "tcp", ARM, np.asarray(target, dtype=np.float64), self.home[:4])
