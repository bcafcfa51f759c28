"""The one tick loop: policy -> executor -> envelope -> robot -> recorder, cycle after cycle.

Simulation and hardware share it. A clock paces it (``SimClock`` steps physics; ``WallClock``
sleeps and spins to each deadline), a cycle source says where a cycle ends, inference is
simulated (simulated time) or runs on a worker (wall time) and never blocks a tick, and the
robot is reached through ``RobotLink`` (watched reads, finite writes). Fault injection is a
simulated cell's concern only: it is applied when the robot is a simulated cell.

Start-up (the first request of the run): the checks of ``startup`` may refuse to move; a first
target far from the measured pose is approached with a limit-respecting trajectory first. A policy
that answers no more (its process ended, a call hung), or whose every answer was refused (failed, rejected,
stale, or dropped unanswered at a cycle's end) while the watchdog held the robot for want of a chunk, stops the run.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from pathlib import Path
from time import perf_counter_ns as perf_ns
from typing import NoReturn

import numpy as np

from cellguard.control.checks.safety_input import RECOVERY_HOLD
from cellguard.control.envelope import STANDSTILL, StaleState
from cellguard.control.events import Event, EventKind
from cellguard.control.executor import PreparedChunk
from cellguard.control.reach import max_reach
from cellguard.control.settings import build_guard
from cellguard.diagnose.cycle_buffer import CycleBuffer
from cellguard.diagnose.features import cycle_features
from cellguard.embodiment.profile import SI_UNITS
from cellguard.errors import ScenarioError
from cellguard.output import make_folder, write_output
from cellguard.policy.chunk import ActionChunk
from cellguard.policy.registry import make_policy
from cellguard.record.session import RunRecording
from cellguard.record.writer import RecordConfig
from cellguard.robot.protocol import RobotLinkError, SafetyInputs
from cellguard.robot.world_changes import apply_world_changes
from cellguard.runtime.build import first_chunk_ns, make_clock, make_inference, make_robot
from cellguard.runtime.cycles import make_cycle_source
from cellguard.runtime.history import CycleWindow, EventLog
from cellguard.runtime.inference import NOMINAL_INFERENCE_S, SimulatedInference
from cellguard.runtime.link import RobotLink
from cellguard.runtime.operator_stop import OperatorStop
from cellguard.runtime.recovery import RecoveryRunner
from cellguard.runtime.startup import BoxStart, StartupRefused, check_startup, duration, watchdog_refusal
from cellguard.runtime.transition_play import TransitionPlay
from cellguard.runtime.transitions import Transition, longest_brake_s
from cellguard.scenario import Scenario

CYCLE_TIMEOUT_S = 12.0  # a cycle that has not finished by then is ended as failed, once no recovery attempt runs [s]
NAN_AFTER_S = 1.0  # a policy_nan fault corrupts the first chunk this long into its cycle [s]
STOP_SETTLE_S = 0.3  # a category 2 stop holds the measured position this long before the run ends [s]
# A call still running this many watchdog times after its request has hung: the policy is lost. The watchdog has
# held the robot since one watchdog time and lets it go on at the next chunk, so a slow call is survived. A policy
# slower than that may still be a live one with long chunks (the start-up check takes a latency up to a horizon,
# and a horizon may be 1000 steps): the bound is also at least HUNG_CALLS times its warm-up call and, once chunks
# come, HUNG_CALLS horizons of the last one (an answer later than that is stale whatever it says).
HUNG_WATCHDOGS = 10
HUNG_CALLS = 2
# The policy's first call (wall time, off the clock) may take this long: it loads and compiles (a large model
# on a cold cache takes minutes). Nothing moves while it runs and Ctrl-C or SIGTERM ends the wait at once, so the
# bound is generous: it only keeps an unattended service from waiting forever on a policy hung in that call.
WARM_UP_TIMEOUT_S = 300.0
# the guard's refusals of an answer, by how the policy-lost rule names them (``_refusal``)
_REFUSED_BY = {EventKind.CHUNK_REJECTED: "rejected", EventKind.CHUNK_STALE: "stale"}
# each refusal's last one, as the policy-lost reason names it among others
_REFUSALS = {"failed": "failure", "rejected": "rejection", "stale": "stale chunk", "dropped": "dropped request"}


class Run(TransitionPlay):
    """One scenario on one robot (a simulated cell or a bridge); ``cycle()`` runs the next cycle."""

    def __init__(self, scenario: Scenario, realtime: bool = False, policy_factory: Callable[[], object] | None = None):
        self.scenario = scenario
        self.cell = make_robot(scenario)
        try:
            self._set_up(scenario, realtime, policy_factory)
        except BaseException:  # a bridge says goodbye: the robot's server need not wait to give up on this client
            close_if_any(self.cell)
            raise

    def _set_up(self, scenario: Scenario, realtime: bool, policy_factory: Callable[[], object] | None) -> None:
        self.simulated = hasattr(self.cell, "step")  # fault injection and simulated inference
        if self.simulated:  # a bridge's faults were refused as its scenario was read
            scenario.check_against(self.cell)
        # the link's limits on this robot's period (too short ones refused), as the record and summary state them;
        # a robot that counts lost packets streams its states
        limits = scenario.realtime.for_robot(self.cell.dt_ns, streams=hasattr(self.cell, "dropped"))
        scenario = self.scenario = scenario.model_copy(update={"realtime": limits})
        _check_watchdog(scenario, self.cell.dt_ns)
        # a policy_factory (picklable, for the process worker) replaces the scenario's policy source
        self.policy_factory = policy_factory
        self.policy = (policy_factory() if policy_factory is not None
                       else make_policy(scenario.policy, self.cell, soft_margin=scenario.guard.soft_margin))
        self.clock = make_clock(self.cell, realtime)
        self._cycle_source()  # refused here, before the record starts; the source itself is built at the first
        # cycle, for the policy then in place
        self.guard = build_guard(self.cell, scenario.guard)
        profile, tool = self.cell.profile, self.guard.tool
        # each joint's largest reach by the guard's tool model, for the transitions' tool-speed cap: computed here,
        # off the ticks (15 ms: a stall of the servo loop where a cap comes on mid-transition)
        self._reach = None if tool is None else max_reach(tool, profile.q_min, profile.q_max).norm
        self.events = EventLog()
        self.cycles = CycleWindow()
        rt = scenario.realtime
        self.link = RobotLink(self.cell, self.events, rt.stop_category,
                              stale_ns=round(rt.stale_s * 1e9) if self.clock.realtime else None,
                              drop_budget=rt.drop_budget)
        self.recovery = RecoveryRunner(scenario.recovery, self.cell, self.events) if scenario.recovery else None
        # chunks sized to a cycle's ticks up to its time-out (at most 33 s at 1 kHz in one); a longer one adds chunks
        self.ticks = CycleBuffer(self.cell.profile.dof, round(_limit_s(scenario.cycle) * 1e9 / self.cell.dt_ns) + 1)
        self.recording: RunRecording | None = None  # set by run_scenario, fed every tick
        # called at each cycle end with the cycle's ticks and its outcome, before it is recorded; may add keys
        # to the outcome (the calibration's residual monitor adds ``residual``)
        self.cycle_monitors: list[Callable[[CycleBuffer, dict], None]] = []
        # called on each tick of the cycles after the guard's, with what it was given and what it gave: (t_ns, state,
        # safety, guard, setpoint, events, driving: a recovery feeds the guard, fed: the recovery's chunk pushed on
        # this tick or None); a shadow guard follows the live one with it (``release.shadow``). Never on a
        # transition's ticks. None: one compare a tick
        self.tick_observer: Callable[..., None] | None = None
        self.stopped: str | None = None  # why the run stopped early, if it did
        # why the policy answers no more (its process ended, a call hung, every answer refused: ``_never_answered``)
        self.policy_lost: str | None = None
        # Ctrl-C / SIGTERM / SIGHUP while the cycles run: a stop; a third signal waits while a brake may run
        self.operator = OperatorStop(longest_brake_s(self.cell.profile, self.cell.dt_ns))
        self.inference = None  # built at the first cycle (the policy may be swapped before)
        self.source = None
        self._started = False  # the first chunk has come and the start-up checks passed
        self._clock_started = False
        self._hang_floor_ns = 0  # wall time: how long a call may run before the policy is lost (set at warm-up) [ns]
        self._armed_at = 0
        # the answers not taken since the watchdog was armed or the guard last took a chunk, by how each was refused
        # ("failed", "rejected" for what its chunk says, "stale" for a chunk whose steps had all passed, "held" for a
        # stop in force; "box": the start outside the box and what went further, while that refused each): the last
        # reason of each, and how many failed or were rejected or stale (``_refusal``)
        self._answers: dict[str, str | tuple[str, str]] = {}
        self._refused = 0
        self._first_observation = None
        self._asked_at: int | None = None  # the request waiting for its answer, if any: when it was asked [ns]
        self._asked_latency_ns = 0  # and how long its answer takes (simulated inference) [ns]
        # the cycle in progress: its start [ns], chunk latencies [ns], wall time per call [ns], a pending NaN fault
        self._cycle_start, self._latencies, self._wall_ns, self._corrupt = 0, [], [], False
        # wall time from one cycle's last tick to the next one's first (its end, the next one's start) [ns each]
        self._between_ns: list[int] = []
        self._ticks_ended: int | None = None

    # -- one cycle ---------------------------------------------------------------------------
    def cycle(self) -> dict:
        """Run the next cycle; return its outcome (success, timing, measured poses)."""
        if self.inference is None:
            self.inference = make_inference(self)
            self.source = self._cycle_source()
        index = self.cycles.total
        cell, clock, link, inference, events = self.cell, self.clock, self.link, self.inference, self.events
        if clock.realtime and not self._clock_started:
            self._warm_up()
        self._corrupt = False
        if self.simulated:
            apply_world_changes(cell, [*self.scenario.faults, *self.scenario.process_changes], index)
            extra_s = sum(f.extra_latency_s(index) for f in self.scenario.faults)
            if clock.realtime:  # the policy's own time is real: the fault holds each chunk back by its extra
                inference.extra_ns = round(extra_s * 1e9)
            else:
                inference.latency_ns = round((NOMINAL_INFERENCE_S + extra_s) * 1e9)
            self._corrupt = any(f.corrupts_output(index) for f in self.scenario.faults)
            if self.recovery is not None:
                self.recovery.arm_speed = min((f.recovery_speed(index) for f in self.scenario.faults), default=1.0)
        recovery = self.recovery
        if recovery is not None:
            recovery.begin_cycle()
        self.source.begin(index, clock.now())
        start = link.read(clock.now()).t_ns if self.simulated else clock.now()
        self._cycle_start = start
        rec = self.recording
        if rec is not None:
            rec.begin_cycle(index, self._phase(index), start)
        timeout = start + round(_limit_s(self.scenario.cycle) * 1e9)
        if self._asked_at is not None and isinstance(inference, SimulatedInference):  # dropped by begin_cycle
            self._dropped(start)
        inference.begin_cycle(start)
        first_event, self._latencies, self._wall_ns = events.total, [], []
        ticks = self.ticks
        ticks.clear()
        timed_out = False
        if not self.guard.power and cell.safety().stop is None:  # a category 0/1 stop in the last cycle: the
            # simulated shift's operator resets the cell, never while the stop input is held (IEC 60204-1; the run
            # ends then: see the cycle's end); a robot behind a bridge ends the run instead: see the ticks
            cell.set_power(True)
            self.guard.reset(link.read(start).q)
            events.append(Event(start, EventKind.RESET, "simulated operator reset after a stop with power removed"))
            self._arm(start)  # the no-first-chunk watchdog runs again from the reset
        state = link.read(start)
        if not self._clock_started:
            self._clock_started = True
            clock.start()
            self._arm(start)  # the watchdog runs from the start, not from the first chunk
        # The ticks: what runs every servo period is inline; what runs at the policy's cadence is a call.
        now, advance, timing, finished, operator = clock.now, clock.advance, clock.timing, self.source.finished, self.operator
        slow = timing.recorder_slow  # wall time: why a slow recorder call was slow
        observe = self.tick_observer
        t = now()
        if self._ticks_ended is not None:
            self._between_ns.append(perf_ns() - self._ticks_ended)
        with clock.ticking():  # wall time: the servo thread is a real-time thread while the ticks run
            while True:
                driving = recovery is not None and recovery.drives(t, state, self.guard)
                if driving:  # a recovery behaviour feeds the guard in place of the policy
                    chunk = recovery.chunk(t)
                    if chunk is not None:
                        if rec is not None:
                            rec.chunk(chunk, t, 0)
                        events.extend(self.guard.push(chunk, t))
                else:
                    arrival = inference.take(t)
                    if arrival is not None and self._arrived(arrival, t):  # an approach was played: time moved
                        t, state = now(), link.state
                    if inference.due(t):
                        self._request(t)
                guard = self.guard
                safety = cell.safety()
                stop = asked_by = None
                if link.stop is not None or guard.executor.last_chunk_ns is None or operator.count or self.policy_lost:
                    stop, asked_by = self._stop_input(t, guard)
                if driving and recovery.stop is not None and (stop is None or recovery.stop < stop):
                    stop, asked_by = recovery.stop, RECOVERY_HOLD
                if stop is not None and (safety.stop is None or stop < safety.stop):
                    safety = SafetyInputs(stop, safety.reduced_speed, asked_by)
                setpoint, new = guard.tick(t, state, safety)
                if new:
                    events.extend(new)
                    if not guard.power:
                        self._power_off(t)
                sent = link.write(t, setpoint)
                if observe is not None:  # after the write: an observer never delays what the robot is sent
                    observe(t, state, safety, guard, setpoint, new, driving, chunk if driving else None)
                advance()
                if timing.new_overrun:
                    self._overrun(t)
                t = now()
                state = link.read(t)
                if state is None:  # the link failed before its first state: nothing to record or to hold
                    self.stopped = self.stopped or f"robot link: {link.reason}"
                    break
                if not ticks.add(guard.reference, sent, state) and ticks.dropped == 1:  # once a cycle
                    events.append(Event(t, EventKind.CYCLE_BUFFER_FULL, f"no memory for more of the cycle's ticks "
                                        f"{(t - start) * 1e-9:.0f} s in: the cycle has no tick features (not "
                                        "compared in diagnosis), the record holds every tick"))
                if rec is not None:
                    usage = slow.before() if slow is not None else None
                    began = perf_ns()
                    recorded = rec.tick(t, guard.reference, sent, state)
                    timing.recorder(perf_ns() - began, usage)
                    if not recorded:
                        break
                if link.stop is not None and (link.lost or guard.envelope.stop_complete):
                    self.stopped = self.stopped or f"robot link: {link.reason}"
                    if link.lost and guard.power:  # lost on this tick: the guard never saw it
                        self._remove_power(self._without_link((link.stop, f"robot link, {link.reason}")),
                                           operator.count)
                    break
                if self.policy_lost and guard.envelope.stop_complete:
                    self.stopped = self.stopped or f"policy lost: {self.policy_lost}"
                    break
                if self.stopped and not guard.power:  # a robot behind a bridge lost its power (above)
                    break
                if operator.count and guard.envelope.tracker.stopped and np.abs(state.qd).max() < STANDSTILL \
                        and not isinstance(state, StaleState) and not guard.envelope.removing_power:  # a stale
                    # state's speeds are no standstill; a category 1 stop in force ends the cycle itself (above)
                    self._operator_stop(t)  # already held still (a hand-over hold): the signal came this tick
                    self.stopped = self.stopped or operator.reason
                    break
                if finished(state):
                    break
                if t >= timeout and not (driving and recovery.attempting):
                    timed_out = True
                    break
            if self.guard.envelope.removing_power:  # the cycle ended (its source, the time-out) during a category 1
                # stop: power goes as the stop asks, here (the retreat is not played after it: nothing else removes it)
                self._remove_power((1, self.guard.envelope.stop_reason), operator.count)
        self._ticks_ended = perf_ns()
        if not self.guard.power and cell.safety().stop is not None:
            self.stopped = self.stopped or self._still_held(self.guard.envelope)
        t_end = clock.now()
        stopped = any(e.category is not None for e in events.since(first_event))
        outcome = {"cycle": index, "phase": self._phase(index), **self.source.end(t_end, stopped)}
        outcome["timed_out"] = timed_out  # the time-out ended it (not the task, a stop or the link)
        if recovery is not None:
            outcome.update(recovery.end_cycle(t_end, stopped=self.stopped is not None))
        outcome["inference"] = _wall_latency(self._wall_ns)
        outcome["features"] = cycle_features(cell.profile, ticks, outcome, self._latencies, events.since(first_event))
        if ticks.dropped:  # the buffer could not grow (``cycle_buffer_full``): no tick features, no monitor's reading
            outcome["buffer_full_after_s"] = round((ticks.stamp(ticks.n - 1) - start) * 1e-9, 3)
        for monitor in self.cycle_monitors if not ticks.dropped else ():  # joining its columns would need more still
            monitor(ticks, outcome)
        if self.cycle_monitors:  # a simulated cell's replay of the cycle (wall time: tens of ms): a pause, no tick
            clock.regrid()
        if rec is not None:
            rec.end_cycle(outcome, t_end)
            if rec.failed:
                self._stop_unrecorded(rec.failed)
        self.cycles.append(outcome)
        return outcome

    def _cycle_source(self):
        """The scenario's cycle source for this robot and policy, a time cycle no shorter than the first chunk
        where that is known (simulated inference: ``first_chunk_ns``)."""
        return make_cycle_source(self.scenario.cycle, self.cell, self.policy, first_chunk_ns(self.clock))

    def _arrived(self, arrival, t_ns: int) -> bool:
        """A finished request: its chunk to the guard (the run's first one after the start-up checks), or
        its failure as an event. True when an approach was played (the clock moved on meanwhile)."""
        self._asked_at = None
        if arrival.chunk is None:
            if arrival.lost:  # for good: one event, not one a request
                self._lose_policy(t_ns, arrival.error)
                return False
            self.events.append(Event(t_ns, EventKind.INFERENCE_FAILED, arrival.error))
            self._wall_ns.append(arrival.wall_ns)
            self._refusal(t_ns, "failed", arrival.error)
            return False
        box = None  # a tool point outside the box, and its first target or the way there further out: the cause
        if not self._started:
            if arrival.prepared is None:  # simulated time: checked here, as the worker would have
                arrival = dataclasses.replace(arrival, prepared=self.guard.executor.prepare(arrival.chunk))
            if arrival.prepared.problem is None:
                held = self._held()
                approach = None if held else self._approach(arrival.chunk)
                why, box = (held, None) if held else self._outside(arrival.chunk, approach)
                if why is not None:  # refused as a malformed chunk is: the next one is the first
                    arrival = dataclasses.replace(arrival, prepared=PreparedChunk(0, 0, problem=why))
                if held is not None:  # refused for the moment, not for what it says: the policy answered
                    self._answers["held"] = held
            # a refused or stale chunk is an event below; the next one starts the run (a stale one is checked all the
            # same: a chunk the latency can never fit is refused for that, not waited on as stale till the watchdog)
            if arrival.prepared.problem is None:
                self._check_startup(arrival)
                if self.guard.executor.stale(arrival.prepared, t_ns) is None:
                    arrival = self._start(arrival, approach)
                if arrival is None:  # an approach was played; a fresh request follows
                    return True
        if self.recording is not None:
            self.recording.chunk(arrival.chunk, t_ns, arrival.latency_ns)
        if self.clock.realtime:  # a policy with long chunks may take long: see HUNG_CALLS
            chunk = arrival.chunk
            self.inference.hang_ns = max(self._hang_floor_ns, HUNG_CALLS * chunk.horizon * chunk.dt_ns)
        pushed = self.guard.push(arrival.prepared or arrival.chunk, t_ns)
        self.events.extend(pushed)
        self._latencies.append(arrival.latency_ns)
        self._wall_ns.append(arrival.wall_ns)
        if pushed and pushed[0].kind in _REFUSED_BY:  # a stale chunk can never move the robot: refused as well
            self._refusal(t_ns, _REFUSED_BY[pushed[0].kind], pushed[0].reason, box)
        return False

    def _request(self, t_ns: int) -> None:
        """Hand the policy an observation (a policy_nan fault corrupts the answer once, ``NAN_AFTER_S`` in)."""
        observation = self.cell.observe()
        failed = self.inference.submit(t_ns, observation)
        if failed is not None:
            self.events.append(Event(t_ns, EventKind.INFERENCE_FAILED, failed.error))
            self._wall_ns.append(failed.wall_ns)
            self._refusal(t_ns, "failed", failed.error)
            return
        self._asked_at, self._asked_latency_ns = t_ns, getattr(self.inference, "latency_ns", None)
        self._first_observation = self._first_observation or observation
        if self.recording is not None:
            self.recording.request(t_ns, observation)
        if self._corrupt and t_ns - self._cycle_start >= NAN_AFTER_S * 1e9:
            self.inference.corrupt_pending(_with_nan)
            self._corrupt = False

    # -- start, stops ---------------------------------------------------------------------------
    def _warm_up(self) -> None:
        """Wall time, before the first cycle: one policy call off the clock (a cold policy's first answer
        is not its latency), then a bridge drops the states that queued up meanwhile. The call runs on the
        worker, waited for at most ``WARM_UP_TIMEOUT_S`` and until the operator's signal (the first tick then
        stops the run); one not answered in time, or whose policy process ended, refuses the start."""
        inference, operator = self.inference, self.operator
        began = perf_ns()
        inference.warm_up(self.cell.observe(), WARM_UP_TIMEOUT_S, lambda: operator.count > 0)
        self._hang_floor_ns = max(round(HUNG_WATCHDOGS * self.scenario.guard.watchdog_s * 1e9),
                                  HUNG_CALLS * (perf_ns() - began))
        inference.hang_ns = self._hang_floor_ns
        if operator.count:
            self._operator_stop(self.clock.now(), " during the policy's warm-up")
        elif inference.lost is not None:
            self._refuse(f"start-up: {inference.lost}; not moving")
        else:
            self.policy.reset()
        resync = getattr(self.cell, "resync", None)
        if callable(resync):
            try:
                resync()
            except RobotLinkError as exc:  # the robot went away meanwhile: the first tick stops the run
                self.link.fault(self.clock.now(), EventKind(exc.kind), str(exc))
                self.link.lost = self.link.lost or exc.lost

    def _start(self, arrival, approach: Transition | None):
        """The run's first chunk, its start-up checks passed (``_check_startup``): its ``approach`` if needed.

        Returns the arrival to push, or None when an approach was played (the chunk answered the
        pose before it; a fresh request follows).
        """
        self._started = True
        if approach is None:
            return arrival
        # from a tool point outside the box, checked already against the box grown to hold it (``_outside``)
        outside = self._leaves_box(approach) if self._box_start() is None else None
        if outside is not None:  # planned in joint space: no path inside the box to the first target is sought
            self._refuse(f"start-up: {_approach_to(approach)}: {outside}; not moving")
        self.clock.regrid()  # planned and checked at rest (slowed where its brakes would leave the box: up to a few
        # hundred ms): a pause before the approach, no late tick (it woke 30 ms late)
        held = self._play(approach, "approach", self.clock.now())
        if self.guard.power:  # else a category 0/1 stop aborted it: the guard holds there, power removed
            self.guard = build_guard(self.cell, self.scenario.guard, q0=held)  # where the commands left the robot
        self.clock.regrid()  # that work, the robot at rest, is no late tick
        self._arm(self.clock.now())
        self.source.begin(self.cycles.total, self._armed_at)  # the cycle (and episode) starts at the approached pose
        self.inference.begin_cycle(self._armed_at)  # and resets the policy
        return None

    def _check_startup(self, arrival) -> None:
        """The start-up checks on a first chunk (``startup``): refuse to move, or return."""
        chunk = arrival.chunk
        # Simulated time: the healthy latency; an injected latency fault is an incident to diagnose, not a refusal.
        latency = arrival.latency_ns if self.clock.realtime else round(NOMINAL_INFERENCE_S * 1e9)
        period = self.clock.period_ns
        try:
            check_startup(self.policy, self._first_observation, chunk, latency, period,
                          self.inference.spacing_ns(latency + period, chunk),
                          round(self.scenario.guard.watchdog_s * 1e9))
        except StartupRefused as exc:
            self._refuse(str(exc))

    def _refuse(self, why: str) -> NoReturn:
        """Refuse to start: the refusal in the record (it held only the watchdog's stop), then StartupRefused."""
        self.events.append(Event(self.clock.now(), EventKind.STARTUP_REFUSED, why))
        raise StartupRefused(why) from None

    def _held(self) -> str | None:
        """Why no first chunk may start the run now: a stop in force (an approach played through a category 0
        stop drove unpowered drives, and its new guard forgot the stop). A category 2 stop that has brought the
        command to rest lets it start: the approach checks the inputs."""
        envelope = self.guard.envelope
        if envelope.stop_category is not None and (envelope.stop_category < 2 or not envelope.tracker.stopped):
            return f"first chunk while a category {envelope.stop_category} stop is in force ({envelope.stop_reason}); " \
                   "nothing approached"
        return None

    def _outside(self, chunk: ActionChunk, approach: Transition | None) -> tuple[str | None, tuple[str, str] | None]:
        """Why the run's first chunk may not start it: its target outside the workspace box, the tool point inside
        it (the policy's answer refused); or, the tool point starting outside it (``BoxStart``), its target or its
        ``approach`` on the way further out, with that start and what went further (a target no further out is taken
        to: an approach further out on the way refused the start, exit 2, where a target further out was a rejected
        chunk). Each refused as a malformed chunk is."""
        target, start = self._first_target(chunk), self._box_start()
        if start is None:
            outside = self.guard.envelope.target_problem(target)
            return (None if outside is None else f"first target: {outside}; nothing approached"), None
        what = start.further(self.guard.tool(target))
        if what is None and approach is not None:
            path = self._leaves_box(approach)
            self.clock.regrid()  # that check (3 ms for a 0.24 s approach), at rest before the first chunk, is no tick
            what = None if path is None else f"{_approach_to(approach)}: {path}"
        return (None, None) if what is None else (start.refused(what), (str(start), what))

    def _box_start(self) -> BoxStart | None:
        """The tool point's start where it lies outside the workspace box (None: inside it, or no box or tool model),
        from where the robot was last commanded to be."""
        box, tool = self.guard.config.box, self.guard.tool
        return None if box is None or tool is None else BoxStart.of(box, tool(self.link.last_sent))

    def _approach(self, chunk: ActionChunk) -> Transition | None:
        """The approach to ``chunk``'s first target from where the robot was commanded to be (the measured pose lags
        it: planning from there stepped the command), or None where it is there."""
        return Transition.plan(self.cell.profile, self.link.last_sent, self._first_target(chunk),
                               self.clock.period_ns, **self._commanded_motion(), **self._cap(self.cell.safety()))

    def _first_target(self, chunk: ActionChunk) -> np.ndarray:
        """The pose an approach goes to: the chunk's first action inside the soft limits, where the guard keeps
        the policy's motion (clipped only into the hard limits, an approach ended past the soft ones)."""
        tracker = self.guard.envelope.tracker
        return np.clip(np.asarray(chunk.actions[0], dtype=np.float64), tracker.lo, tracker.hi)

    def _power_removed(self, envelope) -> str:
        """Why the run stopped for good with power off (a robot behind a bridge, or a stop in the last cycle or the
        retreat): the link fault that asked it, else the guard's stop."""
        if self.link.stop is not None:
            return f"robot link: {self.link.reason}"
        return (f"power removed by a category {envelope.stop_category} stop ({envelope.stop_reason}); reset the cell "
                "and start a new run")

    def _still_held(self, envelope) -> str:
        """Why a simulated cell stays off: the stop input that removed its power is still held at the cycle's end,
        and no reset is allowed while it is (IEC 60204-1). The shift's operator reset it at the next cycle, and
        the stop removed power again at once, cycle after cycle until the time-outs ran out."""
        return (f"power removed by a category {envelope.stop_category} stop ({envelope.stop_reason}) and the stop "
                "input is still held: no reset while it is; clear it, reset the cell and start a new run")

    def _power_off(self, t_ns: int) -> None:
        """Drive power off, the guard having removed it (a category 0 or 1 stop); a robot behind a bridge ends the
        run: power comes back only by a person's deliberate reset (IEC 60204-1)."""
        self.link.power_off(t_ns)
        if not self.simulated:
            self.stopped = self.stopped or self._power_removed(self.guard.envelope)

    def _without_link(self, stop: tuple[int, str | None] | None) -> tuple[int, str | None] | None:
        """A lost link makes a category 1 or 2 stop a 0: a controlled stop is braked by commands over the link, and
        with no state to read and no command that arrives there is no brake to play, no standstill to wait for and
        no hold (a transition waited out the stopping time on the last state read, its brake sent to the dead link;
        a cycle ended with power never switched off, under category 2 with no stop at all)."""
        if stop is not None and stop[0] > 0 and self.link.lost:
            return 0, (f"robot link lost, {self.link.reason}; the category {stop[0]} stop cannot be commanded "
                       "without it")
        return stop

    def _send(self, setpoints, rec) -> np.ndarray:
        """Write each setpoint in its own servo period (read and record after it); return the last."""
        link, clock = self.link, self.clock
        for setpoint in setpoints:
            sent = link.write(clock.now(), setpoint)
            clock.advance()
            t = clock.now()
            state = link.read(t)
            if rec is not None:
                rec.tick(t, setpoint, sent, state)
        return setpoint

    def _stop_input(self, t_ns: int, guard) -> tuple[int | None, str | None]:
        """The stop the loop itself asks for (a robot link fault, an operator stop, or no first chunk within
        the watchdog): the strictest one's category and who asked it; a lost link makes a category 1 or 2 a 0."""
        asked = [] if self.link.stop is None else [(self.link.stop, f"robot link, {self.link.reason}")]
        if self.operator.count:
            self._operator_stop(t_ns)
            asked.append((EventKind.OPERATOR_STOP.category, self.operator.reason))
        if self.policy_lost:
            asked.append((self.scenario.guard.watchdog_category, EventKind.POLICY_LOST.value))
        if guard.executor.last_chunk_ns is None:
            watchdog = self.scenario.guard
            if t_ns - self._armed_at > watchdog.watchdog_s * 1e9:
                if not self.events.has("watchdog_no_first_chunk"):
                    self.events.append(Event(t_ns, EventKind.WATCHDOG_NO_FIRST_CHUNK, f"no chunk within "
                                             f"{watchdog.watchdog_s * 1e3:.0f} ms of the start",
                                             category=watchdog.watchdog_category))
                if self._refused > 1 and not self.policy_lost:
                    self._never_answered(t_ns)
                asked.append((watchdog.watchdog_category, EventKind.WATCHDOG_NO_FIRST_CHUNK.value))
        return self._without_link(min(asked, key=lambda a: a[0], default=None)) or (None, None)

    def _operator_stop(self, t_ns: int, during: str = "") -> None:
        """The operator's first signal, once in the record: mid-cycle the run ends at standstill and the retreat
        follows; during a transition it aborts it."""
        if not self.events.has(EventKind.OPERATOR_STOP):
            self.events.append(Event(t_ns, EventKind.OPERATOR_STOP, f"{self.operator.signal}: the operator asked a "
                                     f"stop{during}", category=EventKind.OPERATOR_STOP.category))

    def _arm(self, t_ns: int) -> None:
        """(Re)start the weighing of answers at ``t_ns`` (the start, a reset, the approach, a chunk taken): the
        no-first-chunk watchdog runs from then, and the answers refused count from then on (``_refusal``)."""
        self._armed_at, self._answers, self._refused = t_ns, {}, 0

    def _refusal(self, t_ns: int, kind: str, why: str, box: tuple[str, str] | None = None) -> None:
        """An answer not taken (``kind``: "failed", "rejected", "stale" or "dropped": ``_dropped``), weighed with those
        since the arming or the last chunk the guard took, whichever came later (the policy's or a recovery's). Once a
        chunk has been taken, the guard's watchdog holds the robot after ``watchdog_s`` without one, and a refused
        answer then, every one since refused, loses the policy (``_never_answered``): a policy that turned bad after
        it started (a NaN in every chunk, every answer later than its own horizon) was asked on, every cycle waited out
        its time-out and the run exited 0. Before the first chunk ``_stop_input`` weighs them at the watchdog.
        ``box``: the tool point's start outside the box, and what of the first target went further out (``_outside``);
        kept while every answer refused is such a one (``_never_answered`` names the start once)."""
        last = self.guard.executor.last_chunk_ns
        if last is not None and last > self._armed_at:  # taken since: the count starts again from it
            self._arm(last)
        self._answers[kind] = why
        if box is None or (self._refused and "box" not in self._answers):
            self._answers.pop("box", None)
        else:
            self._answers["box"] = box
        self._refused += 1
        if (last is not None and self._refused > 1 and not self.policy_lost
                and t_ns - self._armed_at > self.scenario.guard.watchdog_s * 1e9):
            self._never_answered(t_ns)

    def _dropped(self, t_ns: int) -> None:
        """The cycle ended with its request unanswered: simulated inference drops it as the next cycle begins and
        resets the policy (a worker's call in flight arrives late). Weighed as a refused answer: with cycles shorter
        than the answer (2 ms ones, a 10 ms latency) every request was dropped, none refused, and the run counted
        every cycle with the robot held by the watchdog and exited 0, never having moved."""
        asked, self._asked_at = self._asked_at, None  # and its latency then: the next cycle's may differ (a fault's)
        self._refusal(t_ns, "dropped", f"the cycle ended {(t_ns - asked) * 1e-6:.0f} ms after the request, whose "
                                       f"answer takes {self._asked_latency_ns * 1e-6:.0f} ms")

    def _never_answered(self, t_ns: int) -> None:
        """No chunk within the watchdog (of its arming or the last chunk taken) and every answer since refused, two
        at least (one late bad answer of a slow policy whose next is good is no loss): every call failed (a
        server that answers only errors, a model that raises on every observation), or the guard rejected its
        chunk (not finite, beyond the limits, the wrong shape, its first target outside the box from inside it, or,
        from a tool point that starts outside it, the target or the way there further out: the line names that start
        once, the last refusal after it without it; 430 characters named it twice) or it came stale (all its
        steps past: it can never move the robot). The policy is
        lost: the run went on asking it, one event per request, every cycle waited out its time-out, failed, and
        it ended clean, exit 0. A cold one that answers within the watchdog is not, nor one
        whose chunks a stop in force held back (the moment's refusal, not the policy's)."""
        answers = self._answers
        if "held" in answers:
            return
        last = self.guard.executor.last_chunk_ns
        none = "none taken" if last is None else f"none taken since t = {self._armed_at * 1e-9:.3f} s"
        kinds = [kind for kind in _REFUSALS if kind in answers]
        chunks = " or ".join(kind for kind in kinds if kind != "failed")
        if "box" in answers:  # where the tool is, not the policy alone: every answer refused since was such a one
            start, what = answers["box"]
            self._lose_policy(t_ns, f"{start}, every first target or the way to it further out, {none} (the last: "
                                    f"{what})")
            return
        if kinds == ["failed"]:
            lead = "every call failed before the first chunk" if last is None else f"every call failed, {none}"
        elif kinds == ["rejected"]:
            lead = f"the guard rejected every chunk, {none}"
        elif kinds == ["dropped"]:
            lead = f"every cycle ended before the policy's answer came, {none}"
        elif "dropped" in kinds:  # a dropped request had no chunk: not "every chunk was ... or dropped"
            lead = f"every answer was refused ({', '.join(k for k in kinds if k != 'dropped')}) or came after its " \
                   f"cycle ended, {none}"
        elif "failed" in kinds:
            lead = f"every call failed or its chunk was {chunks}, {none}"
        else:
            lead = f"every chunk was {chunks}, {none}"
        if len(kinds) == 1:
            the_last = f"the last: {answers[kinds[0]]}"
        else:
            the_last = "; ".join(f"the last {_REFUSALS[kind]}: {answers[kind]}" for kind in kinds)
        self._lose_policy(t_ns, f"{lead} ({the_last})")

    def _lose_policy(self, t_ns: int, why: str) -> None:
        """The policy answers no more (its process ended, a call hung ``HUNG_WATCHDOGS`` watchdog times, or every
        answer was refused past the watchdog: ``_never_answered``): one
        event and the watchdog's stop category (silence for good is what it configures), the run ends once the
        command is at rest and the retreat follows. Each cycle waited out its time-out before, a dead process
        failing every request (an event each 50 ms), and the run ended with nothing stopped."""
        self.policy_lost = why
        self.events.append(Event(t_ns, EventKind.POLICY_LOST, f"{why}; the run stops",
                                 category=self.scenario.guard.watchdog_category))

    def _overrun(self, t_ns: int) -> None:
        timing = self.clock.timing
        budget = self.scenario.realtime.overrun_budget
        if timing.overruns <= 3 or timing.overruns == budget + 1:
            self.events.append(Event(t_ns, EventKind.OVERRUN, f"tick {timing.ticks} woke {timing.max_late_ns * 1e-3:.0f} us "
                                     f"late at most; {timing.overruns} overruns", ))
        if timing.overruns > budget and self.link.stop is None:
            self.link.fault(t_ns, EventKind.OVERRUN_BUDGET, f"{timing.overruns} overruns, budget {budget}")

    def _stop_unrecorded(self, why: str) -> None:
        """Category 2 stop when the record cannot be written: the guard brakes the robot to a standstill and holds
        it, power kept, reading the robot every tick meanwhile (a bridge's unread states overflowed its socket and
        read as lost packets: a false link fault)."""
        t = self.clock.now()
        self.events.append(Event(t, EventKind.RECORD_FAILED, f"an unrecorded run is not allowed: {why}", category=2))
        safety = SafetyInputs(2, False, "the record cannot be written")
        for _ in range(round(STOP_SETTLE_S * 1e9 / self.cell.dt_ns)):
            state = self.link.read(t)
            setpoint, new = self.guard.tick(t, state, safety)
            self.events.extend(new)
            self.link.write(t, setpoint)
            self.clock.advance()
            t = self.clock.now()
        self.stopped = why

    def _phase(self, index: int) -> str:
        return "acceptance" if index < self.scenario.acceptance_cycles else "production"

    def close(self) -> None:
        """Stop the inference worker and close the policy's connections."""
        if self.inference is not None:
            self.inference.close()
        close_if_any(self.policy)
        close_if_any(self.cell)

    def run_cycles(self, on_cycle: Callable[[dict], None] | None = None) -> None:
        """Every cycle of the scenario, until a stop; then the retreat to the home pose."""
        with self.operator:
            # wall time: a cycle's end, and the retreat's brake from a cycle that ended mid-motion, are ticks on the
            # grid, not a pause (the retreat's way home is checked at rest: a pause there, ``retreat``)
            with self.clock.one_stretch():
                for _ in range(self.scenario.total_cycles):
                    outcome = self.cycle()
                    if on_cycle is not None:  # the caller's work (a CLI's progress bar: 2 to 3 ms as it first draws),
                        on_cycle(outcome)  # not the loop's: a pause, never an overrun that stops the run
                        self.clock.regrid()
                    if self.stopped:
                        break
                self.retreat()
            self._at_rest()
            self.operator.motion_over()
        if self.operator.count:  # a signal during the last retreat stops the run too
            self.stopped = self.stopped or self.operator.reason
        if self.link.stop is not None:  # so does a link fault during it (the robot is left where it failed)
            self.stopped = self.stopped or f"robot link: {self.link.reason}"

    def summary(self) -> dict:
        """Per-cycle outcomes, events, and the injected faults as ground truth, kept apart."""
        summary = {
            "scenario": self.scenario.model_dump(mode="json", exclude={"faults", "process_changes"}),
            "context": {**self.cell.context(), "policy": self.policy.source,
                        "policy_sha256": self.policy.content_hash(), "profile_sha256": self.cell.profile.sha256},
            "phases": self.cycles.phases(),
            "cycles": list(self.cycles),
            "events": [e.to_dict() for e in self.events],
            "ground_truth": {"faults": [f.model_dump(mode="json") for f in self.scenario.faults],
                             "process_changes": [c.model_dump(mode="json") for c in self.scenario.process_changes]},
        }
        if self.link.state is not None or getattr(self.cell, "q_home", None) is None:  # else nothing was measured
            summary["from_home"] = self._from_home()
        if self.clock.realtime:
            between = np.asarray(self._between_ns, dtype=np.float64) * 1e-6
            summary["timing"] = {**self.clock.timing.summary(), "scheduler": self.clock.scheduler,
                                 # one cycle's last tick to the next one's first: its end inside the ticks' grid
                                 # (``WallClock.one_stretch``), a longer one a late tick there [ms]
                                 "between_cycles_ms": {"count": len(between), "p50": float(np.median(between))
                                                       if len(between) else 0.0, "max": float(between.max(initial=0))},
                                 "setpoints_refused": self.link.refused,
                                 "packets_dropped": getattr(self.cell, "dropped", 0),
                                 # the recorder's bounded queue off the servo thread [ticks waiting at most]
                                 "recorder_queue_high_water": getattr(self.recording, "high_water", None),
                                 # the longest the writer took to take ticks once told [ticks]: its lag, not batching
                                 "recorder_writer_lag_ticks": getattr(self.recording, "writer_lag", None),
                                 # shared copy-on-write with the recorder's writer, copied before the ticks
                                 "pages_copied_after_fork": getattr(self.recording, "pages_copied", None)}
        return summary

    def _from_home(self) -> list[dict] | None:
        """How far the robot's last measured pose lies from its home pose: per unit (rad, m) the joint farthest from
        it, or None where the robot has no home pose. A stopped run with no retreat event could not tell a robot
        already home from one with no home to go to (``cli.errors``); one maximum over radians and metres named a
        closed gripper's 17 mm and hid an arm joint 9 mrad away."""
        home = getattr(self.cell, "q_home", None)
        if home is None:
            return None
        gap = np.abs(np.asarray(self.link.state.q, dtype=np.float64) - np.asarray(home, dtype=np.float64))
        units = [SI_UNITS[joint.kind]["position"] for joint in self.cell.profile.joints]
        farthest = {}
        for k, unit in enumerate(units):
            if unit not in farthest or gap[k] > gap[farthest[unit]]:
                farthest[unit] = k
        return [{"joint": self.cell.profile.joints[k].name, "distance": float(gap[k]), "unit": unit}
                for unit, k in farthest.items()]


def run_scenario(scenario: Scenario, out: Path, on_cycle: Callable[[dict], None] | None = None,
                 realtime: bool = False, policy_factory: Callable[[], object] | None = None,
                 overwrite: bool = False, run: Run | None = None, record: RecordConfig | None = None,
                 lock: int | None = None) -> dict:
    """Run every cycle of ``scenario`` and write ``out/summary.json``; return the summary.

    A folder that holds a record already is refused unless ``overwrite``. ``run``: the scenario's
    ``Run`` if the caller built it already (every check before ``out`` is created), or a subclass
    that observes the loop (the release's shadow run). ``record``: the recorder's rates (excitation
    records every tick). ``lock``: ``out``'s lock, held by a caller that writes more beside the record; else the
    run holds it until the summary is written."""
    run = run if run is not None else Run(scenario, realtime=realtime, policy_factory=policy_factory)
    with run.operator:  # a signal while the record closes and the summary is written is counted, never fatal
        try:
            out = make_folder(Path(out), "--out")
            run.recording = RunRecording.start(out, run, replace=overwrite, lock=lock,
                                               **({"config": record} if record else {}))  # RecordError: nothing runs
            try:
                run.run_cycles(on_cycle)
            finally:
                if run.operator.count and run.stopped is None:  # a signal after the run's motion, the record still
                    # open: it says so too, unless the run had stopped for its own cause (no protective stop of its)
                    run._operator_stop(run.clock.now(), " after the run's motion had ended")
                    run.stopped = run.operator.reason
                run.recording.events()
                run.recording.close(keep_folder=True)
        finally:
            run.close()
        try:
            summary = _write_summary(run, out)
            if run.operator.count and not run.stopped:  # a signal once the record had closed (or as the summary was
                # written) is the operator's stop all the same (a release ran its next run), in no event of the record
                run.stopped = run.operator.reason
                summary = _write_summary(run, out, after_record=True)
        finally:
            run.recording.release_folder()
    return summary


def _write_summary(run: Run, out: Path, after_record: bool = False) -> dict:
    """``out/summary.json``: the run's summary, why it stopped, whether its record is whole; returned.
    ``after_record``: the stop came once the record had closed, every cycle run: no event of the record tells it."""
    summary = run.summary()
    if run.stopped:
        summary["stopped"] = run.stopped
    if after_record:
        summary["stopped_after_record"] = True
    if run.recording.failed:  # mid-run (the cell was stopped), or only at close: the record is not whole
        summary["record_failed"] = run.recording.failed
    write_output(out / "summary.json", json.dumps(summary, indent=1), "summary")
    return summary


def _check_watchdog(scenario: Scenario, servo_ns: int) -> None:
    """ScenarioError where ``guard.watchdog_s`` is no longer than the least time between chunks, the policy's period
    plus one servo period (a chunk is taken at the next tick): known before the run, refused before its record
    starts (the start-up check refused it once the record had replaced an old one under ``--overwrite``); the
    start-up check adds what the measured latency shows."""
    period_ns = round(1e9 / scenario.policy_hz)
    why = watchdog_refusal(scenario.guard.watchdog_s, period_ns + servo_ns,
                           f"at least {(period_ns + servo_ns) * 1e-6:.0f} ms (the policy's period "
                           f"{duration(period_ns * 1e-9)} at policy_hz {scenario.policy_hz:g}, each chunk taken up "
                           f"to one servo period, {duration(servo_ns * 1e-9)}, late)")
    if why is not None:
        raise ScenarioError(why)


def _limit_s(cycle) -> float:
    """How long a cycle runs before the time-out ends it, unless a recovery attempt runs [s]."""
    return cycle.seconds + CYCLE_TIMEOUT_S if cycle.source == "time" else CYCLE_TIMEOUT_S


def close_if_any(thing) -> None:
    """Close a policy's connections or a robot bridge, if it has any."""
    close = getattr(thing, "close", None)
    if callable(close):
        close()


def _approach_to(approach: Transition) -> str:
    """The approach named in a refusal: by its first target's pose."""
    return f"the approach to the first target {np.round(approach.target, 3).tolist()}"


def _with_nan(chunk: ActionChunk) -> ActionChunk:
    actions = np.array(chunk.actions, dtype=np.float64)
    actions[actions.shape[0] // 2:, 1] = np.nan
    return ActionChunk(actions, chunk.t_obs_ns, chunk.dt_ns, chunk.uncertainty)


def _wall_latency(wall_ns: list[int]) -> dict:
    """Measured (wall-clock) inference time of the cycle's chunks; kept out of the drift features."""
    ms = np.asarray(wall_ns, dtype=np.float64) * 1e-6
    return {"chunks": len(wall_ns), "wall_ms_mean": float(ms.mean()) if len(ms) else 0.0,
            "wall_ms_p99": _percentile(np.sort(ms), 99) if len(ms) else 0.0,
            "wall_ms_max": float(ms.max()) if len(ms) else 0.0}


def _percentile(ascending: np.ndarray, q: float) -> float:
    """``np.percentile(ascending, q)`` (its linear method, the same arithmetic) without its 70 to 300 µs a call,
    spent at a cycle's end inside the ticks."""
    at = (len(ascending) - 1) * (q / 100)
    low = int(at)
    a, b, t = ascending[low], ascending[min(low + 1, len(ascending) - 1)], at - low
    return float(b - (b - a) * (1 - t) if t >= 0.5 else a + (b - a) * t)
