"""Safe transitions: a limit-respecting trajectory between two poses, played before the policy moves
the robot (approach to its first target) and at the end (retreat to the home pose).

Planned once with ruckig under the profile's velocity, acceleration and jerk limits, from rest
to rest; never a jump. A pose within ``tolerance`` of the target needs no transition. One that is
aborted brakes to a standstill under the same limits (``brake``) from where it is.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import ruckig

from cellguard.embodiment import Profile

TOLERANCE = 0.01  # [rad] or [m]: closer than this, no transition is played


@dataclass(frozen=True)
class Transition:
    """A planned trajectory; ``setpoints()`` yields one position (dof,) per servo period."""

    trajectory: object
    target: np.ndarray
    period_ns: int

    @property
    def duration_s(self) -> float:
        return float(self.trajectory.duration)

    @classmethod
    def plan(cls, profile: Profile, start: np.ndarray, target: np.ndarray, period_ns: int,
             tolerance: float = TOLERANCE) -> Transition | None:
        """The transition from ``start`` to ``target`` (clipped into the limits), or None if already there
        or either pose is not finite (ruckig raises on NaN)."""
        target = np.clip(np.asarray(target, dtype=np.float64), profile.q_min, profile.q_max)
        start = np.asarray(start, dtype=np.float64)
        if not (np.isfinite(target).all() and np.isfinite(start).all()) or float(np.abs(target - start).max()) < tolerance:
            return None
        dof = profile.dof
        otg, inp, traj = ruckig.Ruckig(dof), ruckig.InputParameter(dof), ruckig.Trajectory(dof)
        inp.current_position, inp.target_position = start.tolist(), target.tolist()
        inp.current_velocity = inp.current_acceleration = [0.0] * dof
        inp.target_velocity = inp.target_acceleration = [0.0] * dof
        return cls._solve(profile, otg, inp, traj, period_ns)

    def brake(self, profile: Profile, steps: int) -> Transition | None:
        """A standstill from this transition's ``steps``-th setpoint (its position, velocity and acceleration)
        under the profile's limits, or None if it is at rest there. Stopping the setpoints dead at full speed
        stepped the command 63 mrad in one 1 ms tick."""
        position, velocity, acceleration = self.trajectory.at_time(min(steps * self.period_ns * 1e-9,
                                                                       self.duration_s))
        if steps <= 0 or max(map(abs, [*velocity, *acceleration])) < 1e-9:
            return None
        dof = profile.dof
        otg, inp, traj = ruckig.Ruckig(dof), ruckig.InputParameter(dof), ruckig.Trajectory(dof)
        inp.control_interface = ruckig.ControlInterface.Velocity
        inp.synchronization = ruckig.Synchronization.No  # each joint stops as soon as it can (time sync raised)
        inp.current_position, inp.current_velocity, inp.current_acceleration = position, velocity, acceleration
        inp.target_velocity = inp.target_acceleration = [0.0] * dof
        return self._solve(profile, otg, inp, traj, self.period_ns)

    @classmethod
    def _solve(cls, profile: Profile, otg, inp, traj, period_ns: int) -> Transition | None:
        inp.max_velocity = profile.array("velocity").tolist()
        inp.max_acceleration = profile.array("acceleration").tolist()
        inp.max_jerk = profile.array("jerk").tolist()
        try:
            result = otg.calculate(inp, traj)
        except ruckig.RuckigError:  # some states raise instead of returning an error result
            return None
        if result not in (ruckig.Result.Working, ruckig.Result.Finished):
            return None
        end = np.asarray(traj.at_time(traj.duration)[0], dtype=np.float64)
        return cls(traj, end, int(period_ns))

    @property
    def start(self) -> np.ndarray:
        return np.asarray(self.trajectory.at_time(0.0)[0], dtype=np.float64)

    def setpoints(self):
        dt = self.period_ns * 1e-9
        steps = int(np.ceil(self.duration_s / dt))
        for k in range(1, steps + 1):
            position, _, _ = self.trajectory.at_time(min(k * dt, self.duration_s))
            yield np.asarray(position, dtype=np.float64)
