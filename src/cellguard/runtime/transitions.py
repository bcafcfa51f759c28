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
a first target 18 mm above the table dived 145 mm under it on the way, with no event. So does the brake an abort
plays from any of its setpoints (``brake``: the shortest stop there is, so the stopping distance is the motion's to
keep inside, as a safeguarded space allows for it): 25 of 7,904 brakes sampled along the built-in arms' approaches
and retreats took the tool up to 14 mm out. A transition whose brakes would leave the box is replanned slower
(``SLOWER``: a slower motion stops shorter) and played as the first such plan whose brakes all stay inside; where
none does, it is not played, as one whose path leaves the box.

A transition obeys the guard's tool-speed cap (``speed_cap``: the reduced-speed input's, the guard's
``tool_speed_max``) through its joint velocity limits (``velocity_limits``), lowered so that no motion
within them moves the tool faster; a cap that comes on mid-way brakes and replans the rest (``slowed``), which is
checked against the box from rest there before it is played. The retreat went home at 0.66 m/s at the tool with the
reduced-speed input (0.25 m/s) held; the replanned rest, unchecked, went up to 9 mm out of the box.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
import ruckig

from cellguard.control.checks import SpeedCap, Tick
from cellguard.control.checks.safety_input import ReducedSpeedInput
from cellguard.control.checks.tool_speed import ToolSpeedCap
from cellguard.control.checks.workspace import SLACK, at, box_excess, grown_box, mm
from cellguard.control.config import GuardConfig
from cellguard.embodiment import Profile
from cellguard.robot.protocol import SafetyInputs

# where a transition from outside the box may go (``leaves_box``): the box is named by its start (``startup.BoxStart``)
_FROM_OUTSIDE = (f"where it may go from its start outside the workspace box (past no wall further than there, "
                 f"{mm(SLACK)} mm spare)")
TOLERANCE = 0.01  # [rad] or [m]: closer than this, no transition is played
AT_REST = 1e-9  # [unit/s], [unit/s²]: slower than this, a transition is at rest
BRAKE_SLACK_S = 1.0  # [s] wall time a brake may take beyond its own (a simulated cell's runs on a busy host's CPU)
SLOWER = (0.5, 0.25, 0.125)  # the time scales a transition whose brakes leave the box is replanned at (``kept_in_box``)
_BRAKE = "a brake from its setpoint"  # how ``leaves_box`` names a brake that leaves the box
WINDOW = 32  # [setpoints] brakes bounded together (``_brake_leaves``), halved near a wall down to one


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


class _Brake:
    """A brake's trajectory (``Transition._stop``'s) at its setpoints, ``dt`` [s] apart, and its joints' extrema
    between its ends."""

    def __init__(self, trajectory, dt: float):
        self._at, self._dt, self.duration = trajectory.at_time, dt, trajectory.duration
        self._turns = [(j, x.min, x.t_min, x.max, x.t_max) for j, x in enumerate(trajectory.position_extrema)
                       if 0.0 < x.t_min < self.duration or 0.0 < x.t_max < self.duration]
        self._positions: dict[int, list[float]] = {}  # setpoint -> joint positions, each a span's end or two

    def over(self, i: int, j: int) -> tuple[list[float], list[float]]:
        """Each joint's lowest and highest position from setpoint ``i`` to ``j`` of the brake (held at its end):
        between its positions there and an extremum it reaches between. A joint's brake turns back at most once
        (its velocity changes sign at most once before it rests), so it has no other."""
        a, b = self._position(i), self._position(j)
        low, high = [min(x, y) for x, y in zip(a, b)], [max(x, y) for x, y in zip(a, b)]
        t1, t2 = i * self._dt, j * self._dt
        for k, least, t_least, most, t_most in self._turns:
            if t1 <= t_least <= t2:
                low[k] = min(low[k], least)
            if t1 <= t_most <= t2:
                high[k] = max(high[k], most)
        return low, high

    def _position(self, k: int) -> list[float]:
        position = self._positions.get(k)
        if position is None:
            position = self._positions[k] = self._at(min(k * self._dt, self.duration))[0]
        return position


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
    limits: tuple = ()  # the joint velocity limits its way from rest to the target was planned under [unit/s]
    scale: float = 1.0  # its way from rest time-scaled: velocity, acceleration and jerk limits by scale, ², ³
    # (tool, box, reach, what ``leaves_box`` said): the check with the same is not run twice (``kept_in_box``)
    checked: tuple = field(default=(), compare=False, repr=False)

    @property
    def duration_s(self) -> float:
        return float(sum(t.duration for t in self.trajectories))

    @classmethod
    def plan(cls, profile: Profile, start: np.ndarray, target: np.ndarray, period_ns: int,
             tolerance: float = TOLERANCE, velocity=None, acceleration=None, cap: SpeedCap | None = None,
             reach: list[float] | None = None, box=None, tool=None) -> Transition | None:
        """The transition from ``start`` (moving at ``velocity``, ``acceleration``: default at rest) to
        ``target`` (clipped into the limits) under the tool-speed ``cap`` (``velocity_limits``; default none),
        or None if already there at rest or a state is not finite (ruckig raises on NaN). From rest, with the
        guard's ``box`` and ``tool`` model, slower where its brakes would leave the box (``kept_in_box``). One from
        motion is not (a check while the command moves holds it): the retreat and a slowed transition keep their
        way on in the box from rest where the brake leaves the command; ``leaves_box`` checks it whole."""
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
        rest = cls._from_rest(profile, start, target, period_ns, velocity_limits(profile, target - start, cap, reach))
        if rest is None:
            return None
        made = cls(first + rest.trajectories, rest.target, int(period_ns), cap=math.inf if cap is None else cap.cap,
                   brakes=bool(first), limits=rest.limits)
        return made if first else made.kept_in_box(profile, tool, box, reach)

    def kept_in_box(self, profile: Profile, tool, box, reach: list[float] | None) -> Transition:
        """This transition (from rest), or where its path keeps inside ``box`` but a brake from one of its setpoints
        would not, the first replan of it slower (``SLOWER``) whose brakes all keep inside; where none does, this
        one, which ``leaves_box`` then refuses (its check kept: not run again). Without a box or a tool model, this.
        A replan is the same motion time-scaled (velocity, acceleration and jerk limits by s, s², s³: the same path,
        s times the speed), and its brakes, at the profile's full limits, stop shorter: slowed by its velocity
        limits alone, a motion took another path (up to 37 mm off at 1/8), and one near a wall, speeding up at full
        acceleration, was refused at every speed."""
        if box is None or tool is None or reach is None or not self.limits or self.brakes:
            return self
        said = self.leaves_box(profile, tool, box, reach)
        checked = replace(self, checked=(tool, box, reach, said))
        if said is None or not said.startswith(_BRAKE):
            return checked
        for scale in SLOWER:
            slower = self._from_rest(profile, self.start, self.target, self.period_ns, np.asarray(self.limits),
                                     self.scale * scale)
            if slower is None:
                break
            if slower._brake_leaves(profile, tool, *_corners(box), reach) is None:  # its path: this one's
                return replace(slower, cap=self.cap, checked=(tool, box, reach, None))
        return checked

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
        return Transition(self.trajectories[1:], self.target, self.period_ns, cap=self.cap, limits=self.limits)

    def leaves_box(self, profile: Profile, tool, box, reach: list[float] | None) -> str | None:
        """Where this transition's tool point leaves ``box`` [m] on the way, or on a brake from one of its setpoints
        (``brake``, an abort's), why it may not be played; or None. One that starts outside the box keeps to the box
        grown to hold its start (``grown_box``, as the guard lets a motion do): past no wall further than it starts,
        a wall it is inside of staying one. None without a box or a tool model."""
        if box is None or tool is None or reach is None:
            return None
        if self.checked and self.checked[0] is tool and self.checked[1] == box and self.checked[2] is reach:
            return self.checked[3]
        lo, hi = _corners(box)
        said = self._path_leaves(profile, tool, lo, hi, reach)
        if said is not None:
            return said
        brake = self._brake_leaves(profile, tool, lo, hi, reach)
        if brake is None:
            return None
        excess, wall, tip, t = brake
        where = f"out of the workspace box {[list(map(float, corner)) for corner in box]}" if \
            grown_box(tool(self.start), lo, hi) is None else f"past {_FROM_OUTSIDE}"
        return (f"{_BRAKE} {t:.2f} s in (an abort there) would take its tool point {where}, "
                f"{mm(excess)} mm past its {wall} (at {at(tip, lo, hi)} m)")

    def _path_leaves(self, profile: Profile, tool, lo: tuple, hi: tuple, reach: list[float]) -> str | None:
        """Where this transition's own path leaves the box ``lo``..``hi`` (``leaves_box``), or None. Every setpoint
        is checked, one servo period apart (the tool moves at most sum_j reach_j v_j dt between two, ``reach``:
        ``max_reach``'s); those the tool cannot reach a wall by from a checked one are skipped. From outside, the
        grown box shrinks as the tool comes in; once inside, it stays inside."""
        dt, duration = self.period_ns * 1e-9, self.duration_s
        per_step = float(np.dot(reach, profile.array("velocity"))) * dt  # [m] the tool's most in one period
        left, worst = None, None
        allowed = (lo, hi)  # where the tool point may go: the box, grown while it is outside
        for k, tip, grown in _walk(tool, lo, hi, lambda k: self.state_at(min(k * dt, duration))[0],
                                   math.ceil(duration / dt) + 1, per_step):
            t = min(k * dt, duration)
            if left is not None:
                worst = max(worst, (*box_excess(tip, *allowed), t, tip), key=lambda w: w[0])
            elif k > 0 and (out := box_excess(tip, *allowed))[0] > 0.0:  # past the box in force at the setpoint before
                left = worst = (*out, t, tip)
            else:
                allowed = grown or (lo, hi)
        if left is None:
            return None
        first = f"past its {left[1]} {left[2]:.2f} s in (at {at(left[3], lo, hi)} m)"
        if allowed != (lo, hi):  # from outside, never inside: past the grown box, which it never "leaves" (the
            # box itself is named once, by the start a refusal names with it: ``startup.BoxStart``)
            said = f"its tool point goes {mm(worst[0])} mm past {_FROM_OUTSIDE}, first {first}"
            return said if worst is left else f"{said}, the most past its {worst[1]} {worst[2]:.2f} s in"
        said = f"its tool point leaves the workspace box {[[*lo], [*hi]]} {first}"
        if worst is left:
            return f"{said}, {mm(left[0])} mm outside at worst"
        return f"{said}; {mm(worst[0])} mm outside at worst, past its {worst[1]} {worst[2]:.2f} s in"

    def _brake_leaves(self, profile: Profile, tool, lo: tuple, hi: tuple, reach: list[float]) -> tuple | None:
        """The first brake (``brake``) from one of this transition's setpoints that takes the tool point out of the
        box ``lo``..``hi`` (grown to hold a start outside it), as (excess [m], wall, tool point at its worst, its
        setpoint's time [s]); or None.

        A brake from each of thousands of setpoints (ruckig, then the tool along it) took 190 ms a transition, so
        the brakes are bounded a ``WINDOW`` of setpoints at a time. A joint's brake from any state of the window
        lies, at each time into it, between its brakes from the window's lowest and from its highest velocity and
        acceleration (a time-optimal stop never falls behind one from a lower state: its test is in
        test_transition_brake_box.py), offset by the window's lowest and highest position; the tool point over
        those joint ranges lies within sum_j reach_j half-range of the tool point at their middle. A window whose
        bound leaves the box is halved, down to one setpoint: its own brake, exactly."""
        dt = self.period_ns * 1e-9
        states = np.array([self.state_at(k * dt) for k in range(math.ceil(self.duration_s / dt))])  # (N, 3, D)
        boxes = _boxes_in_force(tool, lo, hi, states[:, 0])
        windows = [(i, min(i + WINDOW, len(states))) for i in range(0, len(states), WINDOW)][::-1]
        while windows:
            i, j = windows.pop()
            box = boxes[j - 1]  # the window's smallest: boxes only shrink
            out = self._brakes_out(profile, tool, box, reach, states[i:j])
            if out is not None and j - i == 1:
                excess, tip = out
                return excess, box_excess(tip, *box)[1], tip, i * dt
            if out is not None:
                windows += [((i + j) // 2, j), (i, (i + j) // 2)]  # the earlier half first
        return None

    def _brakes_out(self, profile: Profile, tool, box: tuple, reach: list[float], states: np.ndarray
                    ) -> tuple | None:
        """Where the brakes from ``states`` (n, 3, D: position, velocity, acceleration) may take the tool point out
        of ``box`` (``_brake_leaves``' bound; exact for one state): (excess [m], tool point) at the worst brake
        setpoint found, or None where none can. A span of the brakes' setpoints is bounded whole (each joint
        between its lowest and highest position over it, ``_Brake.over``), halved where that bound leaves the box:
        only near a wall is the tool point needed at every setpoint. Plain floats: a handful of joints."""
        low, high = states.min(axis=0), states.max(axis=0)
        zero, exact = np.zeros(profile.dof), len(states) == 1
        brakes = [self._stop(profile, zero, *side[1:], self.period_ns) for side in (low, high)]
        if None in brakes:  # ruckig refuses a state: one setpoint's brake holds there (``brake``), a bound is none
            return None if exact else (math.inf, None)
        dt = self.period_ns * 1e-9
        lower, upper = (_Brake(brake.trajectories[0], dt) for brake in brakes)
        (x0, y0, z0), (x1, y1, z1) = box
        low, high = low[0].tolist(), high[0].tolist()
        worst, spans = None, [(0, math.ceil(max(lower.duration, upper.duration) / dt))]
        while spans:
            i, j = spans.pop()
            near, far = lower.over(i, j)[0], upper.over(i, j)[1]
            near, far = [q + p for q, p in zip(low, near)], [q + p for q, p in zip(high, far)]
            x, y, z = tool(np.array([0.5 * (a + b) for a, b in zip(near, far)])).tolist()
            excess = max(x0 - x, x - x1, y0 - y, y - y1, z0 - z, z - z1) + 0.5 * sum(
                k * (b - a) for k, a, b in zip(reach, near, far))
            if excess <= 0.0:
                continue
            if i < j:
                spans += [((i + j) // 2 + 1, j), (i, (i + j) // 2)]  # the earlier half first
            elif not exact:
                return excess, (x, y, z)
            elif worst is None or excess > worst[0]:
                worst = excess, (x, y, z)
        return worst

    def slowed(self, profile: Profile, steps: int, cap: SpeedCap | None, reach: list[float] | None, box=None,
               tool=None) -> Transition | None:
        """The rest of this transition from its ``steps``-th setpoint under a lower tool-speed ``cap`` (one came on):
        braked to a standstill under the profile's limits, then on to the target under the cap. None where the cap
        is no lower (or the transition only brakes: it slows down anyway). Its way on from the brake
        (``after_braking``) is a new path: keep it in the box (``kept_in_box``) and check it (``leaves_box``) from
        rest before it is played."""
        if cap is None or cap.cap >= self.cap or self.settles:
            return None
        position, velocity, acceleration = self.state_at(steps * self.period_ns * 1e-9)
        return self.plan(profile, position, self.target, self.period_ns, velocity=velocity,
                         acceleration=acceleration, cap=cap, reach=reach, box=box, tool=tool)

    def brake(self, profile: Profile, steps: int) -> Transition | None:
        """A standstill from this transition's ``steps``-th setpoint (its position, velocity and acceleration)
        under the profile's limits, or None if it is at rest there. Stopping the setpoints dead at full speed
        stepped the command 63 mrad in one 1 ms tick. Not checked here: checked while the command moves, it would
        hold its setpoint for the check (a dead stop), or leave it moving on; the transition was checked for it
        before it was played (``leaves_box``)."""
        position, velocity, acceleration = self.state_at(steps * self.period_ns * 1e-9)
        if max(map(abs, [*velocity, *acceleration])) < AT_REST:  # the first tick too: the command may be moving
            return None
        return self._stop(profile, position, velocity, acceleration, self.period_ns)

    @classmethod
    def _stop(cls, profile: Profile, position, velocity, acceleration, period_ns: int) -> Transition | None:
        """Each joint to a standstill as soon as it can: the shortest stop in every joint (time synchronisation
        raised for some brakes). Stopping the joints together (phase synchronisation) kept the tool on its path, out
        of the box in 3 of 2,988 sampled brakes instead of 22, but let a joint run on up to 222 ms and 157 mrad
        further, the tool up to 72 mm (the worst of 1,000 stops 294 mm against 245): the transition keeps these
        brakes inside instead (``leaves_box``, ``kept_in_box``)."""
        dof = profile.dof
        otg, inp, traj = ruckig.Ruckig(dof), ruckig.InputParameter(dof), ruckig.Trajectory(dof)
        inp.control_interface = ruckig.ControlInterface.Velocity
        inp.synchronization = ruckig.Synchronization.No
        inp.current_position, inp.current_velocity, inp.current_acceleration = (
            np.asarray(x, dtype=np.float64).tolist() for x in (position, velocity, acceleration))
        inp.target_velocity = inp.target_acceleration = [0.0] * dof
        return cls._solve(profile, otg, inp, traj, period_ns)

    @classmethod
    def _from_rest(cls, profile: Profile, start: np.ndarray, target: np.ndarray, period_ns: int,
                   max_velocity: np.ndarray, scale: float = 1.0) -> Transition | None:
        """From ``start`` at rest to ``target`` at rest under the joint velocity limits ``max_velocity`` and the
        profile's acceleration and jerk limits, all time-scaled by ``scale`` (s, s², s³)."""
        dof = profile.dof
        otg, inp, traj = ruckig.Ruckig(dof), ruckig.InputParameter(dof), ruckig.Trajectory(dof)
        inp.current_position, inp.target_position = start.tolist(), target.tolist()
        inp.current_velocity = inp.current_acceleration = [0.0] * dof
        inp.target_velocity = inp.target_acceleration = [0.0] * dof
        made = cls._solve(profile, otg, inp, traj, period_ns, max_velocity * scale, scale)
        return None if made is None else cls(made.trajectories, made.target, int(period_ns),
                                             limits=tuple(map(float, max_velocity)), scale=scale)

    @classmethod
    def _solve(cls, profile: Profile, otg, inp, traj, period_ns: int, max_velocity=None,
               scale: float = 1.0) -> Transition | None:
        inp.max_velocity = (profile.array("velocity") if max_velocity is None else max_velocity).tolist()
        inp.max_acceleration = (profile.array("acceleration") * scale ** 2).tolist()
        inp.max_jerk = (profile.array("jerk") * scale ** 3).tolist()
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


def _corners(box) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The box's (lower, upper) corners as plain floats [m]."""
    return tuple(map(float, box[0])), tuple(map(float, box[1]))


def _walk(tool, lo: tuple, hi: tuple, position, n: int, per_step: float = 0.0):
    """The box in force at each of a transition's setpoints 0 to ``n`` - 1 from its start (``position(k)``: joint
    positions), one walk for its path's check and its brakes' alike: (k, tool point there, the box ``lo``..``hi``
    grown to hold a start outside it, or None: the box itself). The grown box shrinks as the tool point comes in
    (``grown_box``) and is the box itself from the first setpoint inside it on, as the guard's look-ahead holds a
    motion from outside. ``per_step`` [m]: the most the tool point moves from one setpoint to the next; setpoints it
    cannot reach a wall by from one inside the box are skipped (0: none)."""
    k, grown = 0, None
    while k < n:
        tip = np.asarray(tool(np.asarray(position(k), dtype=np.float64)), dtype=np.float64)
        excess = box_excess(tip, lo, hi)[0]
        if k == 0:
            grown = grown_box(tip, lo, hi)
        elif grown is not None:
            grown = grown_box(tip, lo, hi, grown) if excess > 0.0 else None
        yield k, tip, grown
        k += max(1, int(-excess / per_step)) if excess < 0.0 and per_step > 0.0 else 1


def _boxes_in_force(tool, lo: tuple, hi: tuple, positions: np.ndarray) -> list[tuple]:
    """The box a brake from each of ``positions`` (joint setpoints from the start) must keep inside: the one the path
    is held to there (``_walk``). Checked against the start's grown box throughout, a brake 90 ms after the tool came
    in went 9 mm past the ceiling it had come in under."""
    boxes = [(lo, hi)] * len(positions)
    for k, _, grown in _walk(tool, lo, hi, positions.__getitem__, len(positions)):
        if grown is None:  # the box itself from here on
            break
        boxes[k] = grown
    return boxes
