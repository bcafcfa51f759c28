"""Safe transitions: a limit-respecting trajectory between two poses, played before the policy moves
the robot (approach to its first target) and at the end (retreat to the home pose).

Planned once with ruckig under the profile's velocity, acceleration and jerk limits, ending at
rest; never a jump. From a command still moving (a cycle that ended mid-motion) the transition
first brakes it to a standstill under the same limits, then goes from rest to rest: planning from
rest there stopped the command dead (156 times the acceleration limit in one tick). A pose within
``tolerance`` of the target needs no transition. One that is aborted brakes to a standstill under
the same limits (``brake``) from where it is.

A transition keeps the tool point inside the guard's workspace box (``leaves_box``: every setpoint it would send is
checked before it is played; one that leaves the box is not played at all). Planned in joint space, the approach to
a first target 18 mm above the table dived 145 mm under it on the way, with no event. A brake is never checked: it is
the shortest stop there is (``brake``).

A transition obeys the guard's tool-speed cap (``speed_cap``: the reduced-speed input's, the guard's
``tool_speed_max``) through its joint velocity limits (``velocity_limits``), lowered so that no motion
within them moves the tool faster; a cap that comes on mid-way brakes and replans the rest (``slowed``), which is
checked against the box from rest there before it is played. The retreat went home at 0.66 m/s at the tool with the
reduced-speed input (0.25 m/s) held; the replanned rest, unchecked, went up to 9 mm out of the box.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import ruckig

from cellguard.control.checks import SpeedCap, Tick
from cellguard.control.checks.safety_input import ReducedSpeedInput
from cellguard.control.checks.tool_speed import ToolSpeedCap
from cellguard.control.checks.workspace import SLACK, at, box_excess, grown_box, mm
from cellguard.control.config import GuardConfig
from cellguard.embodiment import Profile
from cellguard.robot.protocol import SafetyInputs

TOLERANCE = 0.01  # [rad] or [m]: closer than this, no transition is played
AT_REST = 1e-9  # [unit/s], [unit/s²]: slower than this, a transition is at rest
BRAKE_SLACK_S = 1.0  # [s] wall time a brake may take beyond its own (a simulated cell's runs on a busy host's CPU)


def speed_cap(config: GuardConfig, safety: SafetyInputs) -> SpeedCap | None:
    """The lowest tool-speed cap the envelope's speed checks ask with these inputs: the reduced-speed input's and
    ``tool_speed_max``'s (a transition plays no chunk: the uncertainty gate has nothing to read); None: no cap."""
    tick = Tick()
    tick.safety = safety
    checks = [ReducedSpeedInput(config.reduced_speed)]
    if config.tool_speed_max is not None:
        checks.append(ToolSpeedCap(config.tool_speed_max))
    caps = [cap for cap in (check.request(tick) for check in checks) if cap is not None]
    return min(caps, key=lambda cap: cap.cap, default=None)


def velocity_limits(profile: Profile, travel: np.ndarray, cap: SpeedCap | None,
                    reach: list[float] | None) -> np.ndarray:
    """The profile's joint velocity limits for a motion of ``travel`` (D,), lowered so that sum_j reach_j v_j <= the
    cap: whatever each joint does within its limit, the tool moves no faster (``reach``: each joint's largest reach
    over its range, ``reach.max_reach``). The cap is shared out in proportion to each joint's travel, as the
    tracker shares it along the closing velocity: the joints then take about as long (all scaled alike, the
    joints that travel little held the others back: 7.4 s for a 4.2 s retreat). Without a tool model (``reach``
    None), the cap's playback scale, as the guard's."""
    limits = profile.array("velocity")
    if cap is None:
        return limits
    if reach is None:
        return limits * cap.scale_without_tool
    travel = np.abs(travel)
    along = float(np.dot(reach, travel))  # [m] at the tool at most
    return np.minimum(limits, cap.cap * travel / along) if along > 0.0 else limits


def longest_brake_s(profile: Profile, period_ns: int) -> float:
    """The longest a brake to a standstill takes under the profile's limits (each joint from its velocity and
    acceleration limits), plus ``BRAKE_SLACK_S``: how long a stop signal's brake may run [s]."""
    stop = Transition._stop(profile, np.zeros(profile.dof), profile.array("velocity"), profile.array("acceleration"),
                            period_ns)
    return (0.0 if stop is None else stop.duration_s) + BRAKE_SLACK_S


@dataclass(frozen=True)
class Transition:
    """Planned trajectories played one after the other; ``setpoints()`` yields one position (dof,) per servo period."""

    trajectories: tuple
    target: np.ndarray
    period_ns: int
    settles: bool = False  # only brakes a command to rest, within tolerance of the target: no transition to tell
    cap: float = math.inf  # the tool-speed cap it goes to the target under [m/s]
    brakes: bool = False  # its first trajectory brakes a moving command to rest (``braking``)

    @property
    def duration_s(self) -> float:
        return float(sum(t.duration for t in self.trajectories))

    @classmethod
    def plan(cls, profile: Profile, start: np.ndarray, target: np.ndarray, period_ns: int,
             tolerance: float = TOLERANCE, velocity=None, acceleration=None, cap: SpeedCap | None = None,
             reach: list[float] | None = None) -> Transition | None:
        """The transition from ``start`` (moving at ``velocity``, ``acceleration``: default at rest) to
        ``target`` (clipped into the limits) under the tool-speed ``cap`` (``velocity_limits``; default none),
        or None if already there at rest or a state is not finite (ruckig raises on NaN)."""
        target = np.clip(np.asarray(target, dtype=np.float64), profile.q_min, profile.q_max)
        start = np.asarray(start, dtype=np.float64)
        moving = [np.zeros_like(start) if x is None else np.asarray(x, dtype=np.float64) for x in (velocity, acceleration)]
        if not all(np.isfinite(x).all() for x in (target, start, *moving)):
            return None
        first: tuple = ()
        dt, jerk = period_ns * 1e-9, profile.array("jerk")
        # stopped within one tick under the jerk limit, a command is at rest already (a settled arm's 1e-6 rad/s
        # played a retreat of 0.00 s)
        if (np.abs(moving[0]) > jerk * dt * dt).any() or (np.abs(moving[1]) > jerk * dt).any():
            stop = cls._stop(profile, start, *moving, period_ns)
            if stop is None:
                return None
            first, start = stop.trajectories, stop.target
        if float(np.abs(target - start).max()) < tolerance:
            return cls(first, start, int(period_ns), settles=True, brakes=True) if first else None
        dof = profile.dof
        otg, inp, traj = ruckig.Ruckig(dof), ruckig.InputParameter(dof), ruckig.Trajectory(dof)
        inp.current_position, inp.target_position = start.tolist(), target.tolist()
        inp.current_velocity = inp.current_acceleration = [0.0] * dof
        inp.target_velocity = inp.target_acceleration = [0.0] * dof
        rest = cls._solve(profile, otg, inp, traj, period_ns, velocity_limits(profile, target - start, cap, reach))
        return None if rest is None else cls(first + rest.trajectories, rest.target, int(period_ns),
                                             cap=math.inf if cap is None else cap.cap, brakes=bool(first))

    def braking(self) -> Transition | None:
        """Only the brake this transition starts with (a moving command brought to rest), or None if it starts at
        rest: played before the rest of a retreat is checked, so the check never holds a moving command."""
        if not self.brakes:
            return None
        first = self.trajectories[0]
        end = np.asarray(first.at_time(first.duration)[0], dtype=np.float64)
        return Transition((first,), end, self.period_ns, settles=True, cap=self.cap, brakes=True)

    def after_braking(self) -> Transition | None:
        """What this transition plays once its brake (``braking``) has brought the command to rest: from there to the
        target (all of it where it starts at rest), or None where it only brakes."""
        if self.settles:
            return None
        if not self.brakes:
            return self
        return Transition(self.trajectories[1:], self.target, self.period_ns, cap=self.cap)

    def leaves_box(self, profile: Profile, tool, box, reach: list[float] | None) -> str | None:
        """Where this transition's tool point leaves ``box`` [m] on the way (why it may not be played), or None.
        Every setpoint is checked, one servo period apart (the tool moves at most sum_j reach_j v_j dt between two,
        ``reach``: ``max_reach``'s); those the tool cannot reach a wall by from a checked one are skipped. One that
        starts outside the box keeps to the box grown to hold its start (``grown_box``, as the guard lets a motion
        do): past no wall further than it starts, shrinking as it comes in, and a wall it is inside of stays one.
        None without a box or a tool model."""
        if box is None or tool is None or reach is None:
            return None
        lo, hi = tuple(map(float, box[0])), tuple(map(float, box[1]))
        dt = self.period_ns * 1e-9
        per_step = float(np.dot(reach, profile.array("velocity"))) * dt  # [m] the tool's most in one period
        steps, k, grown, left, worst = math.ceil(self.duration_s / dt), 0, None, None, None
        allowed = (lo, hi)  # where the tool point may go: the box, grown while it is outside
        while k <= steps:
            t = min(k * dt, self.duration_s)
            tip = np.asarray(tool(np.asarray(self.state_at(t)[0], dtype=np.float64)), dtype=np.float64)
            excess = box_excess(tip, lo, hi)[0]
            if k == 0:  # the start
                grown = grown_box(tip, lo, hi)
            elif left is not None:
                worst = max(worst, (*box_excess(tip, *allowed), t, tip), key=lambda w: w[0])
            else:
                allowed = grown or (lo, hi)
                beyond, wall = box_excess(tip, *allowed)
                if beyond > 0.0:
                    left = worst = (beyond, wall, t, tip)
                elif grown is not None:  # once inside, it stays inside
                    grown = grown_box(tip, lo, hi, grown) if excess > 0.0 else None
            k += max(1, int(-excess / per_step)) if excess < 0.0 and per_step > 0.0 else 1
        if left is None:
            return None
        corners = [list(map(float, corner)) for corner in box]
        first = f"past its {left[1]} {left[2]:.2f} s in (at {at(left[3], lo, hi)} m)"
        if allowed != (lo, hi):  # from outside, never inside: past the grown box, which it never "leaves"
            said = (f"its tool point goes {mm(worst[0])} mm past where it may go from its start outside the workspace "
                    f"box {corners} (past no wall further than there, {mm(SLACK)} mm spare), first {first}")
            return said if worst is left else f"{said}, the most past its {worst[1]} {worst[2]:.2f} s in"
        said = f"its tool point leaves the workspace box {corners} {first}"
        if worst is left:
            return f"{said}, {mm(left[0])} mm outside at worst"
        return f"{said}; {mm(worst[0])} mm outside at worst, past its {worst[1]} {worst[2]:.2f} s in"

    def slowed(self, profile: Profile, steps: int, cap: SpeedCap | None,
               reach: list[float] | None) -> Transition | None:
        """The rest of this transition from its ``steps``-th setpoint under a lower tool-speed ``cap`` (one came on):
        braked to a standstill under the profile's limits, then on to the target under the cap. None where the cap
        is no lower (or the transition only brakes: it slows down anyway). Its way on from the brake
        (``after_braking``) is a new path: check it (``leaves_box``) before it is played."""
        if cap is None or cap.cap >= self.cap or self.settles:
            return None
        position, velocity, acceleration = self.state_at(steps * self.period_ns * 1e-9)
        return self.plan(profile, position, self.target, self.period_ns, velocity=velocity,
                         acceleration=acceleration, cap=cap, reach=reach)

    def brake(self, profile: Profile, steps: int) -> Transition | None:
        """A standstill from this transition's ``steps``-th setpoint (its position, velocity and acceleration)
        under the profile's limits, or None if it is at rest there. Stopping the setpoints dead at full speed
        stepped the command 63 mrad in one 1 ms tick. Not checked against the box: it is the shortest stop, and
        checked while the command moves it would hold its setpoint for the check (a dead stop), or leave it moving
        on; where it takes the tool out of the box (``_stop``: 22 of 2,988 sampled brakes, up to 18 mm) nothing
        shorter is left."""
        position, velocity, acceleration = self.state_at(steps * self.period_ns * 1e-9)
        if max(map(abs, [*velocity, *acceleration])) < AT_REST:  # the first tick too: the command may be moving
            return None
        return self._stop(profile, position, velocity, acceleration, self.period_ns)

    @classmethod
    def _stop(cls, profile: Profile, position, velocity, acceleration, period_ns: int) -> Transition | None:
        """Each joint to a standstill as soon as it can: the shortest stop in every joint (time synchronisation
        raised for some brakes). Stopping the joints together (phase synchronisation) kept the tool on its path, out
        of the box in 3 of 2,988 sampled brakes instead of 22, but let a joint run on up to 222 ms and 157 mrad
        further, the tool up to 72 mm (the worst of 1,000 stops 294 mm against 245)."""
        dof = profile.dof
        otg, inp, traj = ruckig.Ruckig(dof), ruckig.InputParameter(dof), ruckig.Trajectory(dof)
        inp.control_interface = ruckig.ControlInterface.Velocity
        inp.synchronization = ruckig.Synchronization.No
        inp.current_position, inp.current_velocity, inp.current_acceleration = (
            np.asarray(x, dtype=np.float64).tolist() for x in (position, velocity, acceleration))
        inp.target_velocity = inp.target_acceleration = [0.0] * dof
        return cls._solve(profile, otg, inp, traj, period_ns)

    @classmethod
    def _solve(cls, profile: Profile, otg, inp, traj, period_ns: int, max_velocity=None) -> Transition | None:
        inp.max_velocity = (profile.array("velocity") if max_velocity is None else max_velocity).tolist()
        inp.max_acceleration = profile.array("acceleration").tolist()
        inp.max_jerk = profile.array("jerk").tolist()
        try:
            result = otg.calculate(inp, traj)
        except ruckig.RuckigError:  # some states raise instead of returning an error result
            return None
        if result not in (ruckig.Result.Working, ruckig.Result.Finished):
            return None
        end = np.asarray(traj.at_time(traj.duration)[0], dtype=np.float64)
        return cls((traj,), end, int(period_ns))

    def state_at(self, t: float):
        """Position, velocity and acceleration ``t`` seconds in (held at the end past it)."""
        for traj in self.trajectories[:-1]:
            if t <= traj.duration:
                return traj.at_time(t)
            t -= traj.duration
        last = self.trajectories[-1]
        return last.at_time(min(t, last.duration))

    @property
    def start(self) -> np.ndarray:
        return np.asarray(self.state_at(0.0)[0], dtype=np.float64)

    def setpoints(self):
        dt = self.period_ns * 1e-9
        steps = int(np.ceil(self.duration_s / dt))
        for k in range(1, steps + 1):
            position, _, _ = self.state_at(min(k * dt, self.duration_s))
            yield np.asarray(position, dtype=np.float64)
