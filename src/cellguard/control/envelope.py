"""Envelope: the last software check between the reference and the robot, once per servo tick.

Inside the envelope the reference sample is sent exactly (see ``tracker``: no filter, no
delay). Around it: soft and hard position limits with stopping-distance look-ahead; velocity,
acceleration and jerk limits; an effort limit on the measured joint efforts; a Cartesian box
for the tool point with its own look-ahead; a tool-speed cap, lowered to the reduced speed
(250 mm/s, ISO 10218-1) when the safety controller asks for it or the policy is unsure; a
watchdog on policy silence; and stops of IEC 60204-1 categories 0, 1 and 2. A category 1 stop removes
power once the machine has stopped: the setpoint at rest and every joint speed of a fresh measured state under
``STANDSTILL`` (a ``StaleState`` shows none: the link could not vouch for it), or one stopping time of the profile
(at least ``SETTLE_MIN_NS``) after the setpoint came to rest whatever the joints read.

Speed is lowered by slowing the executor's playback clock (``scale``), which keeps the path
and stretches time. ``scale`` moves with bounded rate and rate of rate, so the slow-down itself
stays inside the acceleration and jerk limits for a reference inside them. The clock alone does
not cap the setpoints: a policy that answers in real time places each chunk where the program is
now, so the reference jumps ahead of a slowed clock. So where a reference sample would move the
tool faster than the cap, or while the tracker recovers under one, the tracker gets the cap in
joint terms (``reach.ToolCap``: the tool Jacobian's column norms at the setpoint, by finite
differences of ``tool``) and shares it out among the joints (``tracker``). A sample under the cap
passes exactly, and the Jacobian is computed only on the ticks where the cap binds.

This is software, not a safety-rated function: it obeys the certified safety controller's
protective-stop and reduced-speed inputs; it does not replace them.

Every intervention is an ``Event`` with its time, joint, what was asked, what was sent and
why; a lasting condition raises one event when it starts. The checks other than the joint
limits are sibling modules in ``checks/``, each answering a stop or a speed-cap request per tick;
``apply`` combines them in a short loop. A stop asked for after tracking (the box: a stop from the
setpoint just computed may not end inside) replaces that setpoint: the stop starts from the last
one, which was checked the same way a tick earlier.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from cellguard.control.checks import SpeedCap, Stop, Tick, build_checks
from cellguard.control.config import GuardConfig
from cellguard.control.events import Event, EventKind
from cellguard.control.reach import ToolCap, reach_at
from cellguard.control.tracker import PASS, STOP, Tracker
from cellguard.embodiment import Profile
from cellguard.robot.protocol import SafetyInputs
from cellguard.robot.state import State

NO_INPUTS = SafetyInputs()
INTERVENTION_QUIET_NS = 200_000_000  # a joint's intervention is a new event after this long untouched
STANDSTILL = 0.05  # every measured joint speed below this: the machine has stopped [rad/s, m/s]
# A category 1 stop waits at least this long after its setpoint rests for the joints to read still [ns]: a drive
# follows with a lag of its own (the quadruped's loaded legs read still 0.4 to 0.5 s after a 40 ms stopping time)
SETTLE_MIN_NS = 1_000_000_000


class StaleState(State):
    """A measured state its link could not vouch for: stamped out of date (a frozen bus or server), or the last good
    one standing in for a read that failed. Its speeds are no standstill: a category 1 stop
    waits for a fresh state (``runtime.link`` marks them)."""

    __slots__ = ()

    @classmethod
    def of(cls, state) -> StaleState:
        """``state`` marked stale, its fields taken by name: a bridge may hand over any object with them."""
        return cls._make(getattr(state, name) for name in State._fields)


def stopping_time_ns(profile: Profile) -> int:
    """The longest stop the profile lets a joint take [ns]: jerk-limited from full speed, v/a + a/j. A drive
    that follows its setpoint within these limits is at rest this long after the setpoint is, from any speed."""
    v, a, j = (profile.array(k) for k in ("velocity", "acceleration", "jerk"))
    return round(float((v / a + a / j).max()) * 1e9)


class Envelope:
    """Limits, watchdog, gate and stops around a Tracker; ``apply`` once per servo tick.

    ``tool``: joint positions (D,) -> tool point (3,) [m], needed for the box and the tool-speed
    cap. ``scale`` is the speed the executor's playback clock should run at next tick.
    """

    def __init__(self, profile: Profile, q0: np.ndarray, dt_ns: int, config: GuardConfig | None = None,
                 tool: Callable[[np.ndarray], np.ndarray] | None = None):
        self.profile, self.config, self.dt_ns, self._tool = profile, config or GuardConfig(), int(dt_ns), tool
        c = self.config
        lo, hi = profile.q_min, profile.q_max
        self.tracker = Tracker(q0, profile.array("velocity"), profile.array("acceleration"), profile.array("jerk"),
                               *profile.soft_limits(c.soft_margin), dt_ns * 1e-9)
        checks = build_checks(profile, c, self.dt_ns, tool, self.tracker)
        self._stops, self._speeds, self._after, self._all = (
            checks.stops, checks.speeds, checks.after, checks.stops + checks.speeds + checks.after)
        self._tick = Tick()
        # tool point of the last setpoint [m], plain floats: three coordinates are cheaper so on the tick
        self._tip = None if tool is None else tuple(tool(np.asarray(q0, dtype=np.float64)).tolist())
        self.scale, self._scale_rate = 1.0, 0.0
        self.stop_category: int | None = None  # of the stop in force
        self.stop_kind: EventKind | None = None
        self.stop_reason: str | None = None
        self.power = True
        self._rest_ns: int | None = None  # when the setpoint of the category 1 stop in force came to rest
        self._stale_since: int | None = None  # since when that stop at rest has met only stale states (``StaleState``)
        # then how long the measured joints may take to follow it
        self._settle_ns = max(stopping_time_ns(profile), SETTLE_MIN_NS)
        self._active: dict[EventKind, str] = {}  # lasting conditions already reported, with their reason
        self.tool_speed = 0.0  # [m/s] of the last setpoint
        self._last_intervention = [-(2**62)] * profile.dof  # per joint [ns]
        # per joint: the last tick it was braked [ns], and before which soft limit (the upper: True)
        self._last_brake = [(-(2**62), False)] * profile.dof
        self._mid = (0.5 * (lo + hi)).tolist()  # a braked joint's setpoint above this brakes before the upper limit
        self._names = profile.joint_names

    # -- the tick ------------------------------------------------------------------------
    def apply(self, t_ns: int, reference: np.ndarray, state=None, safety: SafetyInputs = NO_INPUTS,
              last_chunk_ns: int | None = None, uncertainty: float = 0.0,
              tool_speed_ahead: Callable[[], float | None] | None = None) -> tuple[np.ndarray, list[Event]]:
        """The setpoint (D,) for this tick and the events raised; never raises on bad values.

        ``tool_speed_ahead``: the fastest tool speed of the chunk ahead [m/s] (None: unknown), asked
        only while a speed cap is in force.
        """
        events: list[Event] = []
        tracker, tick = self.tracker, self._tick
        finite = all(map(math.isfinite, reference.tolist()))  # cheaper than np.isfinite on (D,)
        tick.t_ns, tick.reference, tick.finite, tick.state, tick.safety = t_ns, reference, finite, state, safety
        tick.last_chunk_ns, tick.uncertainty, tick.stop_kind = last_chunk_ns, uncertainty, self.stop_kind
        request = None
        for check in self._stops:
            r = check.request(tick)
            if r is not None:
                if r.detail is not None:
                    events.append(r.detail)
                if request is None or r.category < request.category:
                    request = r
        resumed = None  # the stop cleared on this tick, and where its event is
        if request is not None:
            self._begin_stop(t_ns, request, events)
        elif self.stop_category == 2 and tracker.stopped:
            resumed = (self.stop_category, self.stop_kind, self.stop_reason), len(events)
            events.append(Event(t_ns, EventKind.RESUME, f"cleared: {self.stop_reason}"))
            self.stop_category = self.stop_kind = self.stop_reason = None
            self._settle_tool()
        if self.stop_category is not None:
            if not self.power:
                return tracker.hold(), events
            setpoint = tracker.stop(reference if finite else None)
            if self.stop_category == 1 and tracker.stopped:
                self._end_category_1(t_ns, state, events)
            return setpoint, events
        cap = self._update_scale(tick, tool_speed_ahead, events)
        before = tracker.mode  # the modes before this tick (the tracker replaces its list, never changes it)
        was = tracker.snapshot() if self._after else None
        tip = tool_cap = None
        if cap is not None and self._tool is not None:
            tip, tool_cap = self._tool_cap(reference, cap)
        setpoint = tracker.follow(reference, tool_cap)
        if tracker.failed is not None:  # ruckig refused its input: this tick braked every joint
            events.append(Event(t_ns, EventKind.TRACKER_FAILED, f"ruckig: {tracker.failed}; braking this tick"))
            tracker.failed = None
        if not tracker.passing:
            self._report_tracking(t_ns, reference, setpoint, before, events)
        if self._tool is not None:
            tip_was = self._tip
            self._follow_tool(tick, setpoint, tip if setpoint is reference else None)
            for check in self._after:
                r = check.request(tick)
                if r is not None:
                    self._tip = tip_was
                    return self._refuse(tick, r, was, resumed, events), events
        return setpoint, events

    def _refuse(self, tick: Tick, stop: Stop, was: tuple, resumed, events: list[Event]) -> np.ndarray:
        """A stop from the setpoint just computed may not fit: the stop starts from the last one instead
        (``was``, checked a tick ago), and a stop cleared on this same tick (``resumed``) simply holds on."""
        if resumed is not None and resumed[0][1] == stop.kind:
            (self.stop_category, self.stop_kind, self.stop_reason), at = resumed
            del events[at]
        else:
            self._begin_stop(tick.t_ns, stop, events)
        self.tracker.restore(was)
        setpoint = self.tracker.stop(tick.reference)
        self._follow_tool(tick, setpoint)
        return setpoint

    def target_problem(self, q: np.ndarray) -> str | None:
        """Why the pose ``q`` may not be a transition's target: its tool point lies outside the box (a transition
        to the policy's first target is played outside the ticks' checks; it drove the tool above the box)."""
        box = self.config.box
        if box is None or self._tool is None:
            return None
        tip = self._tool(np.asarray(q, dtype=np.float64))
        if not ((np.asarray(box[0]) <= tip) & (tip <= np.asarray(box[1]))).all():
            return (f"its tool point {np.round(tip, 3).tolist()} m lies outside the workspace box "
                    f"{[list(map(float, corner)) for corner in box]}")
        return None

    def to_dict(self) -> dict:
        """The settings in force, for the record's context (JSON types)."""
        return self.config.model_dump(mode="json")

    def reset(self, q: np.ndarray) -> None:
        """Operator reset after a stop: power back on, standstill at ``q`` (measured)."""
        self.tracker.reset(q)
        self.stop_category = self.stop_kind = self.stop_reason = None
        self.power = True
        self._rest_ns = self._stale_since = None
        self._active.clear()
        for check in self._all:
            check.reset()
        self.scale, self._scale_rate = 1.0, 0.0
        self._settle_tool()

    def _settle_tool(self) -> None:
        """Tool point of the setpoint at standstill: the tool-speed estimate restarts from rest."""
        if self._tool is not None:
            self._tip = tuple(self._tool(self.tracker.p).tolist())

    def _tool_cap(self, reference: np.ndarray, cap: float) -> tuple[tuple, ToolCap | None]:
        """The tool point of ``reference``, and the cap [m/s] in joint terms at the setpoint where the reference
        sample would break it or the tracker is not passing through (else None: the sample passes as it is)."""
        tip = x, y, z = tuple(self._tool(reference).tolist())
        px, py, pz = self._tip
        if math.sqrt((x - px) ** 2 + (y - py) ** 2 + (z - pz) ** 2) * 1e9 <= cap * self.dt_ns and self.tracker.passing:
            return tip, None
        return tip, ToolCap(cap, reach_at(self._tool, self.tracker.p, self._tip))

    def _follow_tool(self, tick: Tick, setpoint: np.ndarray, tip: tuple | None = None) -> None:
        """The tool point of ``setpoint`` (``tip`` if already known) into ``tick``, its finite-difference speed
        into ``tool_speed``."""
        x, y, z = self._tool(setpoint).tolist() if tip is None else tip
        px, py, pz = self._tip
        self._tip = tick.tip = (x, y, z)
        self.tool_speed = math.sqrt((x - px) ** 2 + (y - py) ** 2 + (z - pz) ** 2) * 1e9 / self.dt_ns

    # -- stops -----------------------------------------------------------------------------
    @property
    def stop_complete(self) -> bool:
        """The stop in force has run its course: power removed (category 0 at once, 1 once the machine has
        stopped), or the setpoint of a category 2 stop at rest."""
        return not self.power or (self.stop_category == 2 and self.tracker.stopped)

    @property
    def removing_power(self) -> bool:
        """A category 1 stop is in force, power still on: only its own end (``stop_complete``) may end a cycle or
        a run, else nothing removes power."""
        return self.stop_category == 1 and self.power

    def _begin_stop(self, t_ns: int, stop: Stop, events: list[Event]) -> None:
        category = stop.category
        if self.stop_category is not None and self.stop_category <= category:
            return  # a stop at least as strict is already in force
        self.stop_category, self.stop_kind, self.stop_reason = category, stop.kind, stop.reason
        events.append(Event(t_ns, stop.kind, stop.reason, category=category))
        if category == 0 and self.power:
            self.power = False
            events.append(Event(t_ns, EventKind.POWER_REMOVED, f"category 0 stop: {stop.reason}", category=0))

    def _end_category_1(self, t_ns: int, state, events: list[Event]) -> None:
        """With the setpoint at rest, power off once the machine has stopped (IEC 60204-1 category 1): every joint
        speed of a fresh measured state below ``STANDSTILL``, or ``_settle_ns`` later whatever they read (a robot that
        never reads still, or whose link gives only stale states, must not keep power). A ``StaleState`` never shows
        standstill: a frozen link's last speeds are no measurement of now (a lost link is the link's category 0).
        The event names the fastest joint, its speed (asked) and the threshold (sent), and the stale states passed
        over. Without a measured state (benchmarks) the setpoint at rest is all there is to go by."""
        reason = f"category 1 stop complete: {self.stop_reason}"
        if state is None:
            self.power = False
            events.append(Event(t_ns, EventKind.POWER_REMOVED, reason, category=1))
            return
        if self._rest_ns is None:
            self._rest_ns = t_ns
        stale, waited = isinstance(state, StaleState), t_ns - self._rest_ns
        if not stale:
            stale_since, self._stale_since = self._stale_since, None  # a fresh state ends the stale stretch
        elif self._stale_since is None:
            self._stale_since = t_ns
        j = None if stale else int(np.abs(state.qd).argmax())
        speed = math.nan if stale else abs(float(state.qd[j]))
        if not speed < STANDSTILL:  # a speed that reads NaN (or none read: stale) is no standstill either
            if waited < self._settle_ns:
                return
            reason = (f"category 1 stop: {'no fresh state to read standstill from' if stale else 'still moving'} "
                      f"{waited * 1e-6:.0f} ms after the setpoint came to rest, power removed anyway: "
                      f"{self.stop_reason}")
        elif stale_since is not None:
            reason += (f"; standstill read from a fresh state after {(t_ns - stale_since) * 1e-6:.0f} ms of "
                       "stale ones")
        self.power = False
        events.append(Event(t_ns, EventKind.POWER_REMOVED, reason, joint=None if j is None else self._names[j],
                            asked=None if stale else speed, sent=None if stale else STANDSTILL, category=1))

    # -- speed -----------------------------------------------------------------------------
    def _update_scale(self, tick: Tick, speed_ahead: Callable[[], float | None] | None,
                      events: list[Event]) -> float | None:
        """The lowest tool-speed cap the speed checks ask for sets the playback speed; conditions reported.
        Returns that cap [m/s], None if none is in force."""
        cap: SpeedCap | None = None
        without_tool = 1.0
        on = None
        for check in self._speeds:
            r = check.request(tick)
            if r is not None:
                if cap is None or r.cap < cap.cap:
                    cap = r
                without_tool = min(without_tool, r.scale_without_tool)
                if r.condition is not None:
                    on = [r] if on is None else on + [r]
        if on is not None or self._active:
            self._conditions(tick.t_ns, on or (), events)
        target = 1.0
        if cap is not None:
            speed = None if speed_ahead is None else speed_ahead()
            if speed is None:
                target = without_tool
            elif speed > 0.0:
                target = min(1.0, 0.9 * cap.cap / speed)
        self._ramp(target)
        return None if cap is None else cap.cap

    def _ramp(self, target: float) -> None:
        """Move ``scale`` toward ``target`` with bounded rate and rate of rate (a 2nd-order slew)."""
        c, dt = self.config, self.dt_ns * 1e-9
        err = target - self.scale
        if err == 0.0 and self._scale_rate == 0.0:
            return
        # the rate that still stops on target with the acceleration bound
        wanted = math.copysign(min(c.scale_rate, math.sqrt(2.0 * c.scale_accel * abs(err))), err) if err else 0.0
        step = c.scale_accel * dt
        self._scale_rate += min(max(wanted - self._scale_rate, -step), step)
        self.scale = min(max(self.scale + self._scale_rate * dt, 0.0), 1.0)
        if abs(target - self.scale) < 1e-6 and abs(self._scale_rate) < step:
            self.scale, self._scale_rate = target, 0.0

    # -- reporting ---------------------------------------------------------------------------
    def _conditions(self, t_ns: int, on, events: list[Event]) -> None:
        """One event when a lasting condition starts, one when it clears."""
        now = {r.condition: r.reason for r in on}
        for kind, reason in now.items():
            if kind not in self._active:
                events.append(Event(t_ns, kind, reason))
        for kind, reason in list(self._active.items()):
            if kind not in now:
                events.append(Event(t_ns, EventKind(f"{kind}_cleared"), reason))
        self._active = now

    def _report_tracking(self, t_ns, reference, setpoint, before, events) -> None:
        """One event per joint when the tracker takes it over after a stretch of pass-through, and one when it
        brakes the joint before a soft limit after a stretch unbraked or before the other limit. A joint held at
        its soft limit by a reference beyond it may switch between braking and recovery every few ticks (the
        recovery's plan carries the others' motion): that is one brake, not one event per switch."""
        mode, last, braked, mid = self.tracker.mode, self._last_intervention, self._last_brake, self._mid
        brakes = []
        for j, (now, was) in enumerate(zip(mode, before)):
            if now == PASS:
                continue
            if now == STOP:
                upper = setpoint[j] > mid[j]
                t_was, upper_was = braked[j]
                if was != STOP and (t_ns - t_was >= INTERVENTION_QUIET_NS or upper != upper_was):
                    brakes.append(j)
                braked[j] = (t_ns, upper)
            elif was == PASS and t_ns - last[j] >= INTERVENTION_QUIET_NS:
                events.append(Event(t_ns, EventKind.LIMIT_INTERVENTION, "reference outside the velocity, acceleration, "
                                    "jerk or position envelope; ruckig takes over", joint=self._names[j],
                                    asked=float(reference[j]), sent=float(setpoint[j])))
            last[j] = t_ns
        for j in brakes:
            events.append(Event(t_ns, EventKind.LIMIT_BRAKE, "braking: a stop no longer fits before the soft limit",
                                joint=self._names[j], asked=float(reference[j]), sent=float(setpoint[j])))
