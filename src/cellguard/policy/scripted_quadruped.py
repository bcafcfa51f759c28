"""A trot gait controller for the quadruped cell, emitted as action chunks.

It follows the commands in the observation the way a joystick gait does: ``speed_command``
[m/s] forward and ``yaw_rate_command`` [rad/s] (positive turns left), open loop, without
feedback on the yaw rate actually reached, so a weak side shows as a turn that differs from
its mirror. Feet move under each hip: in stance at the velocity that carries the body along
the commanded arc, in swing on a quintic that matches the stance velocity at lift-off and
touchdown, lifted by ``swing_height``; joint targets come from the leg's closed-form inverse
kinematics.

A turn is planned once, from the command in the cycle's first observation, as a left turn; a
right turn is its exact mirror through the profile's symmetry map (left and right joints
swapped, abduction negated), so a healthy robot turns equally both ways. The gait starts at
the first observation of a cycle, ramps up over one period and, once the command has dropped
to zero, ramps down over one period from the next period boundary and stops at the following
one, all four feet down, in the stance.
"""

from __future__ import annotations

import mujoco
import numpy as np

from cellguard.embodiment import Profile
from cellguard.errors import ConfigError
from cellguard.policy.chunk import ActionChunk
from cellguard.policy.protocol import Policy, behaviour_hash
from cellguard.robot.quadruped_cell import ASSETS, LEGS
from cellguard.robot.state import Observation

DIAGONAL_PHASE = {"fl": 0.0, "rr": 0.0, "fr": 0.5, "rl": 0.5}  # trot: diagonal pairs in phase
RAMP_LEAD_S = 0.1  # [s] the ramp-down starts at a period boundary at least this far ahead


def _smoothstep(u: np.ndarray) -> np.ndarray:
    u = np.clip(u, 0.0, 1.0)
    return u * u * u * (10.0 - 15.0 * u + 6.0 * u * u)


def _smoothstep_rate(u: np.ndarray) -> np.ndarray:
    """d/du of ``_smoothstep``."""
    u = np.clip(u, 0.0, 1.0)
    return 30.0 * u * u * (1.0 - u) * (1.0 - u)


class ScriptedQuadrupedPolicy(Policy):
    """Emits ``horizon`` steps of ``dt`` seconds of the trot, from the observation's commands.

    ``period`` [s] is the gait cycle, ``duty`` the share of it each foot is down, ``swing_height``
    [m] the foot lift. Steps of 10 ms keep the executor's spline close to the plan (about 10 mrad rms).
    """

    source = "scripted"

    def __init__(self, profile: Profile, horizon: int = 30, dt: float = 0.01, period: float = 0.5,
                 duty: float = 0.6, swing_height: float = 0.06):
        self.horizon, self.dt_ns = horizon, round(dt * 1e9)
        self.period, self.duty, self.swing_height = period, duty, swing_height
        model = mujoco.MjModel.from_xml_path(str(ASSETS / "quadruped.xml"))
        names = profile.joint_names
        # Leg geometry as taught from the nominal model: hips, link lengths, the stance.
        self._hips = np.array([model.body(f"{leg}_hip").pos for leg in LEGS])  # (4, 3) [m] body frame
        self._thigh = float(-model.body(f"{LEGS[0]}_calf").pos[2])  # [m]
        self._calf = float(-model.site(f"{LEGS[0]}_foot").pos[2])  # [m]
        stand = model.key("stand").ctrl
        self.stand = np.array([stand[model.actuator(n).id] for n in names])
        self._cols = np.array([[names.index(f"{leg}_{j}") for j in ("abduction", "hip", "knee")] for leg in LEGS])
        hip, knee = self.stand[self._cols[0, 1]], self.stand[self._cols[0, 2]]
        self._height = self._thigh * np.cos(hip) + self._calf * np.cos(hip + knee)  # [m] hip above foot
        self._offset = np.array([DIAGONAL_PHASE[leg] for leg in LEGS])
        self._mirror, self._sign = _mirror_map(profile)
        self._t0_ns: int | None = None
        self._t_down: float | None = None  # [s] after t0: ramp-down start, once the command is off
        self._command = np.zeros(2)  # (speed [m/s], |yaw rate| [rad/s]) of this turn
        self._right = False

    def reset(self) -> None:
        """A new turn: the next observation starts the gait and sets its command."""
        self._t0_ns, self._t_down = None, None

    def content_hash(self) -> str:
        return behaviour_hash(self, self.horizon, self.dt_ns, self.period, self.duty, self.swing_height, self.stand,
                              self._hips, self._thigh, self._calf, self._cols, self._mirror, self._sign,
                              (ASSETS / "quadruped.xml").read_bytes())

    def infer(self, observation: Observation) -> ActionChunk:
        speed = float(observation.measurements["speed_command"][0])
        yaw_rate = float(observation.measurements["yaw_rate_command"][0])
        now = observation.t_ns
        if self._t0_ns is None:
            self._t0_ns = now
            self._command = np.array([speed, abs(yaw_rate)])
            self._right = yaw_rate < 0.0
        elapsed = (now - self._t0_ns) * 1e-9
        if self._t_down is None and speed == 0.0 and yaw_rate == 0.0:
            self._t_down = np.ceil((elapsed + RAMP_LEAD_S) / self.period) * self.period
        t = elapsed + (np.arange(self.horizon) + 1) * self.dt_ns * 1e-9
        q = self._left_turn(t)
        if self._right:
            q = self._sign * q[:, self._mirror]
        return ActionChunk(actions=q, t_obs_ns=now, dt_ns=self.dt_ns)

    # -- The gait, planned as a left turn ----------------------------------------------------
    def _scale(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Share of the commanded velocities at ``t`` [s] and its rate [1/s]: up, then down once off."""
        up, d_up = _smoothstep(t / self.period), _smoothstep_rate(t / self.period) / self.period
        if self._t_down is None:
            return up, d_up
        u = (t - self._t_down) / self.period
        down, d_down = 1.0 - _smoothstep(u), -_smoothstep_rate(u) / self.period
        return up * down, d_up * down + up * d_down

    def _left_turn(self, t: np.ndarray) -> np.ndarray:
        """Joint targets (H, dof) at times ``t`` (H,) [s] for the commanded left turn."""
        speed, yaw_rate = self._command
        hips = self._hips
        # Body velocity at each hip (4, 3); a stance foot moves at minus this in the body frame.
        body = np.stack([speed - yaw_rate * hips[:, 1], yaw_rate * hips[:, 0], np.zeros(4)], axis=1)
        stance, swing = self.duty * self.period, (1.0 - self.duty) * self.period
        phase = np.mod(t[:, None] / self.period + self._offset[None, :], 1.0)  # (H, 4)
        in_stance = phase < self.duty
        # Stance: pass under the hip at mid-stance; its velocity includes the ramp's rate.
        tau = phase * self.period
        feet = (self._scale(t)[0][:, None, None] * body[None]) * (stance / 2.0 - tau)[:, :, None]
        # Swing: from the lift-off point to the touchdown point, matching the stance velocity at both.
        sigma = np.clip((phase - self.duty) / (1.0 - self.duty), 0.0, 1.0)
        t_lift = t[:, None] - sigma * swing
        s_lift, r_lift = self._scale(t_lift)
        s_land, r_land = self._scale(t_lift + swing)
        p_lift, p_land = (-s_lift * stance / 2.0)[..., None] * body, (s_land * stance / 2.0)[..., None] * body
        v_lift = (-s_lift - r_lift * stance / 2.0)[..., None] * body
        v_land = (-s_land + r_land * stance / 2.0)[..., None] * body
        g = sigma[:, :, None]
        g3 = g ** 3
        h0 = 1.0 - 10.0 * g3 + 15.0 * g3 * g - 6.0 * g3 * g * g
        h1 = g - 6.0 * g3 + 8.0 * g3 * g - 3.0 * g3 * g * g
        h4 = -4.0 * g3 + 7.0 * g3 * g - 3.0 * g3 * g * g
        swing_feet = h0 * p_lift + (1.0 - h0) * p_land + swing * (h1 * v_lift + h4 * v_land)
        swing_feet[:, :, 2] += self.swing_height * 64.0 * (sigma * (1.0 - sigma)) ** 3
        feet = np.where(in_stance[:, :, None], feet, swing_feet)
        if self._t_down is not None:  # stopped: every foot back in the stance
            feet[t >= self._t_down + self.period] = 0.0
        feet[:, :, 2] -= self._height
        return self._inverse_kinematics(feet)

    def _inverse_kinematics(self, feet: np.ndarray) -> np.ndarray:
        """Joint angles (H, dof) placing each foot at ``feet`` (H, 4, 3) [m] from its hip."""
        x, y, z = feet[..., 0], feet[..., 1], feet[..., 2]
        abduction = np.arctan2(y, -z)
        zp = -np.hypot(y, z)
        l1, l2 = self._thigh, self._calf
        c = np.clip((x * x + zp * zp - l1 * l1 - l2 * l2) / (2.0 * l1 * l2), -1.0, 1.0)
        knee = -np.arccos(c)
        hip = np.arctan2(-x, -zp) - np.arctan2(l2 * np.sin(knee), l1 + l2 * np.cos(knee))
        q = np.empty((feet.shape[0], len(self.stand)))
        q[:, self._cols[:, 0]] = abduction
        q[:, self._cols[:, 1]] = hip
        q[:, self._cols[:, 2]] = knee
        return q


def _mirror_map(profile: Profile) -> tuple[np.ndarray, np.ndarray]:
    """Column permutation and signs so that ``sign * q[:, perm]`` is the mirror of ``q``."""
    names = profile.joint_names
    perm, sign = np.arange(len(names)), np.ones(len(names))
    for pair in profile.symmetry:
        left, right = names.index(pair.left), names.index(pair.right)
        perm[left], perm[right] = right, left
        sign[left] = sign[right] = pair.sign
    unpaired = [n for i, n in enumerate(names) if perm[i] == i]
    if unpaired:
        raise ConfigError(f"symmetry: joints {', '.join(unpaired)} have no mirror; the gait needs every joint paired")
    return perm, sign
