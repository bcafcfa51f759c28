"""Recoveries in the loop: when the cell reports a failed check, the scenario's recovery behaviour
drives the cell in place of the policy, through the same guard (chunks in, envelope on every tick).

Each attempt is a ``recovery_start`` / ``recovery_end`` event pair; the end says (in words, and as fields in
``Event.recovery``, as the cycle's ``recovery_log``) how long it took, when the arm arrived at its contact pose
(measured) against when the gripper was told to shut, and the outcome: ``resumed`` (its plan ran out with no
failed check: the cell carries on; after a plan with no contact, a rehome or an operator hand-over, with the next
cycle, this one failed, so the cycle's ``recovery_resumed`` leaves it out), ``failed`` (another attempt follows),
``escalated`` (its ``then`` follows), ``gave_up`` (nothing left, or the per-cycle limit: the cell goes home),
``cut_off`` (the cycle ended while the attempt waited for its arm after a failed check or was held by a stop, a stop
of the run ended it, or a category 0 or 1 stop removed the power mid-plan: no attempt starts after it in that
cycle). The cell's task ending the cycle before the plan ran out, with no failed check, is ``resumed``: the task
judged the cycle done (the arm home and still, 75 ms before an operator hand-over's plan ended). Once a recovery has
started it drives the cell to the end of the cycle, and the cycle's time-out waits for the attempt in progress
(``attempting``): an operator hand-over holds for its whole ``hold_s`` and ends in its reset, and no attempt is left
mid-move for the next cycle's policy to start from (an operator hold of 30 s was cut off after 6 s and the cell
moved again with no reset). Attempts are bounded by ``attempts``, acyclic escalation or ``max_per_cycle``. A failed
check during an attempt ends it once the arm has reached its contact pose (or the plan has passed it): a controller
finishes the move in progress before it reacts. A category 2 stop (power kept) holds the arm and pauses the
attempt's plan until it clears, as a controller pauses its program: the plan's clock running on under the stop shut
the gripper before the held arm arrived, the very signature the diagnosis reads as a late recovery. Arrival and
close times are plan times; the duration is the time the attempt took. The cycle's time-out does not wait for a held
attempt (a stop that never clears, such as a workspace stop waiting for a reference that no longer moves, would hold
the cycle for ever): the time-out ends it ``cut_off``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cellguard.control.checks.safety_input import ASKED_BY_LOOP, RECOVERY_HOLD
from cellguard.control.events import Event, EventKind
from cellguard.control.guard import Guard
from cellguard.policy.chunk import ActionChunk
from cellguard.robot.recovery import Plan, RecoveryPolicy
from cellguard.robot.recovery.base import PlanError, go_home
from cellguard.robot.recovery.outcome import RecoveryOutcome

ARRIVE_TOL = 0.01  # [rad or m] every arm joint this close to the contact pose: the tool has arrived
WAIT_S = 0.3  # [s] of plan time past the close that a failed attempt waits for the arm to arrive
STEPS, STEP_NS = 25, 20_000_000  # chunks of 25 steps of 20 ms, as the taught program's


@dataclass
class _Attempt:
    behaviour: object
    trigger: str
    attempt: int
    plan: Plan
    t0: int  # the plan's time origin: moved on while a stop holds the arm, so the plan waits for it
    start: int  # when the attempt began [ns]
    arrived_ns: int | None = None  # plan time of the arrival at the contact pose [ns]
    failed_ns: int | None = None
    reset_ns: int | None = None  # an operator hand-over: when the operator reset the cell
    left: bool = False  # the arm has been away from the contact pose (an arrival counts only after)


class RecoveryRunner:
    """Starts, watches and ends recoveries for one run; ``arm_speed`` is set per cycle (a fault's override)."""

    def __init__(self, policy: RecoveryPolicy, cell, events):
        policy.check_against(cell)
        self.policy, self.cell, self.events = policy, cell, events
        self._failed_check = getattr(cell, "failed_check", lambda: None)  # a robot without checks never triggers
        self.arm_speed = 1.0
        self._log: list[RecoveryOutcome] = []
        self.begin_cycle()

    def begin_cycle(self) -> None:
        self._previous = len(self._log)  # recoveries of the cycle before: the next cycle's context
        self._active: _Attempt | None = None
        self._tail: tuple[Plan, int] | None = None  # after a recovery: its plan's end, or home, held
        self._home_by = 0  # after the last attempt gave up: when the move home ends [ns]
        self._next_chunk = 0
        self._log: list[RecoveryOutcome] = []
        self._origin: np.ndarray | None = None  # the reference when the cycle's first check failed
        self._now = 0
        self._held = False  # a category 2 stop holds the arm (see _follow)
        self._powered = True  # False after a category 0 or 1 stop: nothing moves until a reset
        self.held_at_end = False  # the cycle ended (an operator stop) while a hand-over hold was in force

    @property
    def attempting(self) -> bool:
        """An attempt, or the move home after the last one gave up, is in progress: the cycle's time-out waits
        for it to end (a move home cut off mid-way started the next cycle 1 rad from home). Not an attempt that
        another stop holds: its plan waits for the stop, the time-out does not (a stop that never clears)."""
        return (self._active is not None and not self._held) or self._now < self._home_by

    @property
    def stop(self) -> int | None:
        """Category 2 while an operator hand-over holds the cell (power kept)."""
        a = self._active
        return 2 if a is not None and a.plan.hold_s and self._now - a.t0 < a.plan.hold_s * 1e9 else None

    def drives(self, t: int, state, guard: Guard) -> bool:
        """Once per tick, before the guard's tick: True while a recovery drives the cell (from a failed check to
        the cycle's end). ``guard``: its reference and the stop in force."""
        reference = guard.reference
        a = self._active
        if self._follow(guard.stop) and a is not None:
            self._end(a, t, "cut_off")  # a stop removed the power: the plan did not run out
            self._tail = (a.plan, a.t0)
            a = None
        elif a is not None and self._held and self.stop is None:
            a.t0 += t - self._now  # the plan waits while a stop holds the arm, as a paused program does
        self._now = t
        failed = self._failed_check()
        if a is None:
            if self._tail is not None:
                return True
            behaviour = self.policy.for_trigger(failed) if failed and self._powered else None
            if behaviour is None:
                return False
            self._origin = np.array(reference, dtype=np.float64)
            self._begin(behaviour, failed, 1, t, reference)
            return True
        if a.plan.hold_s and a.reset_ns is None and t - a.t0 >= a.plan.hold_s * 1e9:
            a.reset_ns = t
            self.events.append(Event(t, EventKind.RESET, f"operator reset after the hand-over ({a.trigger})"))
        if a.plan.contact_q is not None and a.arrived_ns is None:
            near = float(np.abs(state.q[:-1] - a.plan.contact_q).max()) < ARRIVE_TOL
            a.left = a.left or not near
            if near and a.left:
                a.arrived_ns = t - a.t0
        if failed and a.failed_ns is None:
            a.failed_ns = t
        if a.failed_ns is not None:
            passed = a.plan.close_t is None or (t - a.t0) * 1e-9 * self.arm_speed > a.plan.close_t + WAIT_S
            if a.arrived_ns is not None or passed:
                self._after_failure(a, t, reference)
        elif t - a.t0 >= a.plan.duration(self.arm_speed) * 1e9:
            self._end(a, t, "resumed")
            self._active, self._tail = None, (a.plan, a.t0)
        return True

    def chunk(self, t: int) -> ActionChunk | None:
        """The next chunk of the recovery driving the cell, once per policy period; else None."""
        if t < self._next_chunk:
            return None
        self._next_chunk = t + STEP_NS
        plan, t0 = (self._active.plan, self._active.t0) if self._active is not None else self._tail
        times = (t - t0 + (np.arange(STEPS) + 1) * STEP_NS) * 1e-9
        return ActionChunk(plan.sample(times, self.arm_speed), t, STEP_NS)

    def end_cycle(self, t: int, stopped: bool = False) -> dict:
        """The cycle's recovery outcome fields (flat, SI) and its log; ``t``: when the cycle ended. An attempt still
        running when the cell's task ended the cycle with no failed check resumed the cell (the task judged the
        cycle done before the plan's last moves ran out); one with a failed check, held by a stop, or ended by a
        stop of the run (``stopped``: the operator, the robot link), was cut off. One a stop of the run ended is
        stamped at ``t`` (stamped at the cycle's last tick, it read before the stop that cut it); any other at the
        cycle's last tick."""
        a = self._active
        self.held_at_end = self.stop is not None
        if a is not None:
            cut = a.failed_ns is not None or self.held_at_end or stopped or self._held
            self._end(a, t if stopped else self._now, "cut_off" if cut else "resumed")
            self._active = None
        log = self._log
        out = {"recoveries": len(log), "recoveries_failed": sum(o.outcome != "resumed" for o in log),
               "recovery_resumed": float(any(o.resumed_cell() for o in log)),
               "recovery_s": float(sum(o.duration_s for o in log)), "after_recovery": float(self._previous > 0)}
        contact = [o for o in log if o.close_s is not None]
        if contact:  # both of one attempt: one's arrival against another's close read as a shut no attempt made
            latest = max(reversed(contact), key=_arrival_after_close)  # a tie: the later attempt
            out["recovery_close_s"] = float(latest.close_s)
            if latest.arrival_s is not None:
                out["recovery_arrival_s"] = float(latest.arrival_s)
        if log:
            out["recovery_log"] = [o.to_dict() for o in log]
        return out

    def _follow(self, stop: tuple[int, str] | None) -> bool:
        """Follow the guard's stop in force; True on the tick a category 0 or 1 stop is first seen (it removes the
        power: nothing starts again this cycle). A category 2 stop other than the runner's own hand-over hold
        holds the arm (and the plan) while it lasts."""
        category, reason = stop if stop is not None else (None, None)
        self._held = category == 2 and reason != ASKED_BY_LOOP + RECOVERY_HOLD
        if category is not None and category < 2 and self._powered:
            self._powered = False
            return True
        return False

    # -- attempts -----------------------------------------------------------------------------------
    def _begin(self, behaviour, trigger: str, attempt: int, t: int, reference: np.ndarray) -> None:
        limit = self.policy.max_per_cycle
        if limit is not None and len(self._log) >= limit:
            self._give_up(t, reference, f"the limit of {limit} recoveries per cycle")
            return
        try:
            plan = self._plan(behaviour, attempt, reference)
        except ValueError as exc:  # a pose the arm cannot reach: a search offset, a lift from where it is
            self._unplanned(behaviour, attempt, t, reference, str(exc), "a plan the arm cannot reach")
            return
        except Exception as exc:  # noqa: BLE001 - a behaviour's bug (a plugin's) fails the cycle, not the run
            self._unplanned(behaviour, attempt, t, reference, f"{type(exc).__name__}: {exc}",
                            f"{behaviour.do} could not make a plan")
            return
        self._active = _Attempt(behaviour, trigger, attempt, plan, t, t)
        self._next_chunk = t
        self.events.append(Event(t, EventKind.RECOVERY_START, f"{behaviour.do}: attempt {attempt} of "
                                 f"{behaviour.attempts} after {trigger}"))

    def _plan(self, behaviour, attempt: int, reference: np.ndarray) -> Plan:
        """The behaviour's plan for this attempt, checked against the arm: the loop samples it on every tick, where
        a wrong type or width would end the run."""
        plan = behaviour.plan(self.cell, np.asarray(reference, dtype=np.float64), attempt, self._origin)
        if not isinstance(plan, Plan):
            raise PlanError(f"plan() returned a {type(plan).__name__}, not a Plan")
        joints = len(reference) - 1
        for name in ("arm_q", "contact_q"):
            value = getattr(plan, name)
            if value is not None and np.shape(value)[-1:] != (joints,):
                raise PlanError(f"its {name} has shape {np.shape(value)}, for an arm of {joints} joints")
        return plan

    def _unplanned(self, behaviour, attempt: int, t: int, reference: np.ndarray, error: str, why: str) -> None:
        """An attempt that cannot be planned is logged naming its behaviour and the error; then nothing is left."""
        self.events.append(Event(t, EventKind.RECOVERY_END, f"{behaviour.do}: attempt {attempt} cannot be "
                                 f"planned ({error})"))
        self._give_up(t, reference, why)

    def _after_failure(self, a: _Attempt, t: int, reference: np.ndarray) -> None:
        b = a.behaviour
        limit = self.policy.max_per_cycle
        if (a.attempt < b.attempts or b.then is not None) and limit is not None and len(self._log) + 1 >= limit:
            self._end(a, t, "gave_up")  # the last one the limit allows: nothing follows it
            self._give_up(t, reference, f"the limit of {limit} recoveries per cycle")
        elif a.attempt < b.attempts:
            self._end(a, t, "failed")
            self._begin(b, a.trigger, a.attempt + 1, t, reference)
        elif b.then is not None:
            self._end(a, t, "escalated")
            self._begin(self.policy.behaviour(b.then), f"escalation from {b.do}", 1, t, reference)
        else:
            self._end(a, t, "gave_up")
            self._give_up(t, reference, f"{b.do} failed {b.attempts} time(s)")

    def _give_up(self, t: int, reference: np.ndarray, why: str) -> None:
        """Nothing left to try: the cell goes home (a plan that cannot fail, so nothing is left to handle here)
        and the cycle ends failed."""
        self._active = None
        home = go_home(self.cell, np.asarray(reference, dtype=np.float64), 1.0)
        self._tail, self._home_by = (home, t), t + round(home.duration(self.arm_speed) * 1e9)
        self.events.append(Event(t, EventKind.RECOVERY_END, f"no recovery left ({why}): home, the cycle fails"))

    def _end(self, a: _Attempt, t: int, outcome: str) -> None:
        arrival = a.arrived_ns * 1e-9 if a.arrived_ns is not None and a.plan.close_t is not None else None
        close = a.plan.close_t
        done = RecoveryOutcome(a.behaviour.do, a.trigger, a.attempt, outcome, round((t - a.start) * 1e-9, 3),
                               *(None if v is None else round(v, 3) for v in (arrival, close)))
        self._log.append(done)  # in the cycle's row, at its end; the event is recorded now
        self.events.append(Event(t, EventKind.RECOVERY_END, done.reason(),
                                 recovery={k: v for k, v in done.to_dict().items() if v is not None}))
        self._active = None


def _arrival_after_close(o: RecoveryOutcome) -> float:
    """How long after its gripper was told to shut an attempt arrived at contact [s] (negative: before; never: the
    latest of all): the cycle's ``recovery_arrival_s`` and ``recovery_close_s`` are the latest such attempt's."""
    return math.inf if o.arrival_s is None else o.arrival_s - o.close_s
