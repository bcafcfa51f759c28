"""Shadow mode: the candidate answers the live observations next to the incumbent, never actuating.

The incumbent keeps driving. Each time it is asked for a chunk, the candidate is asked the same
observation; its answer goes into a guard of its own (``cellguard.control.guard.Guard``, built
with the candidate's envelope settings) on the tick the loop takes the incumbent's, and that guard
follows the live one tick by tick (``Run.tick_observer``): the same measured state and safety inputs
(reduced speed, stops; not the loop's stops for the incumbent's own silence), a recovery's chunks while
one drives (the live guard goes on from them), rebuilt after the approach, unpowered while it is after a stop
removed power and reset with it. It never writes to the robot. Per candidate chunk we keep
``command_distance_rad``: the largest gap between what the two guards command over the chunk's span of
ticks (max over joints [rad]), where the candidate's envelope shows (a tool-speed cap slows its playback:
its raw chunk is the incumbent's); ``distance_rad``, the raw chunks' distance as before; and whether its guard clamped it (a limit
intervention, or its playback slowed where the live one's was not) or stopped it (a stop of any
category) in that span. An intervention the live guard made on the same tick for the same reason is
not the candidate's. The loop's watchdog before the first chunk lives in the loop, not in a guard, so
the shadow keeps its own: a candidate whose chunks the guard never takes (every one NaN) would be
stopped live within ``watchdog_s`` (it counted 0 stops). Written to ``shadow.json`` beside the record.

On wall time the shadow guard's tick runs on the servo thread after the tick's command was written and before the
wait for the next deadline: it never delays what the robot is sent, it spends the tick's slack (a 1 kHz arm or
SO-101 cell: about 30 us a tick at p50, 60-70 us at p99; the tick's compute p50 rose 25-30 us, p99 30-80 us, no more
overruns). Kept there: it reads the live guard as it is on that tick (its power, speed scale, a guard rebuilt); on
another thread each tick's would be copied and queued. The candidate is asked after the incumbent, in its call: a
slow candidate's time is charged to the incumbent's latency, and its own is not measured (nor a stale answer's).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from cellguard.control.guard import Guard
from cellguard.control.events import NO_INTERVENTION, EventKind
from cellguard.control.config import GuardConfig
from cellguard.control.settings import build_guard
from cellguard.errors import ConfigError
from cellguard.output import write_output
from cellguard.policy.chunk import ActionChunk
from cellguard.policy.registry import make_policy
from cellguard.release.evidence import SHADOW_FILE
from cellguard.release.reductions import action_at
from cellguard.robot.protocol import SafetyInputs
from cellguard.runtime import Run
from cellguard.runtime.loop import close_if_any
from cellguard.scenario import Scenario

SPEED_SCALED = "speed_scaled"  # the candidate's playback slowed where the live one's was not: no event of the guard's
# the guard's speed conditions: their effect is the slowing, counted as that against the live guard's
_SLOWING = frozenset({EventKind.REDUCED_SPEED_INPUT, EventKind.REDUCED_SPEED_INPUT_CLEARED, EventKind.UNCERTAINTY_GATE,
                      EventKind.UNCERTAINTY_GATE_CLEARED})
# the loop's stops asked for the incumbent's own silence: the candidate's guard reads the controller's inputs instead
_INCUMBENTS = frozenset({EventKind.WATCHDOG_NO_FIRST_CHUNK.value, EventKind.POLICY_LOST.value})
DISTANCES = ("distance_rad", "command_distance_rad")


class ShadowedPolicy:
    """The incumbent behind the Policy protocol, with the candidate computed beside it; ``tick`` follows the live
    guard (the run's ``tick_observer``)."""

    def __init__(self, incumbent, candidate, cell, config: GuardConfig, guard: Guard, cycle):
        self.incumbent, self.candidate, self.cell, self.config, self.guard = incumbent, candidate, cell, config, guard
        self.cycle = cycle
        self.source = incumbent.source
        self.map_document = getattr(incumbent, "map_document", None)  # the record's map is the incumbent's
        self.rows: list[dict] = []
        self._pending: tuple[dict, ActionChunk | None] | None = None  # the candidate's answer, till the loop takes
        # taken by the loop on this tick, with the live guard's events on taking the incumbent's
        self._taking: tuple[dict, ActionChunk | None, list] | None = None
        self._open: dict | None = None  # the row of the candidate chunk now in the shadow guard
        self._live: Guard | None = None  # the live guard the shadow's follows (another: the approach rebuilt it)
        self._live_power = True
        self._first_chunk_by: int | None = None  # the shadow's start plus the watchdog [ns]; None once checked
        self._watchdog_ns = round(config.watchdog_s * 1e9)
        self._told = False  # the first-chunk watchdog, once a run as the loop's

    def content_hash(self) -> str:
        return self.incumbent.content_hash()

    def close(self) -> None:
        """Both policies' connections (an openpi server's): the run closes the policy it drives, which is this one."""
        try:
            close_if_any(self.candidate)
        finally:
            close_if_any(self.incumbent)

    def reset(self) -> None:
        self.incumbent.reset()
        self.candidate.reset()

    def infer(self, observation):
        chunk = self.incumbent.infer(observation)  # what drives; a failure here is the run's event
        row = {"t_ns": int(observation.t_ns), "cycle": int(self.cycle()), "distance_rad": None,
               "command_distance_rad": None, "events": [], "clamped": False, "stopped": False}
        candidate = None
        try:  # the whole candidate side: whatever it answers, it never fails the incumbent's inference
            candidate = self.candidate.infer(observation)
            if not isinstance(candidate, ActionChunk):
                raise TypeError(f"the candidate answered {type(candidate).__name__}, not an ActionChunk")
            row["distance_rad"] = _distance(chunk, candidate)
        except Exception as exc:  # noqa: BLE001 - a failing candidate is a would-be stop, never the incumbent's
            row.update(events=[f"inference_failed: {type(exc).__name__}"], stopped=True)
            candidate = None
        self.rows.append(row)
        self._pending = row, candidate  # one the loop drops (a new cycle's start) is never taken
        return chunk

    def taken(self, approached: bool, pushed: list) -> None:
        """The loop took the incumbent's answer on this tick, the live guard raising ``pushed`` (a chunk it refused:
        stale, NaN): the candidate's goes into its guard on it (``tick``), a refusal the live guard made alike not
        the candidate's, unless an approach was played instead (then neither is: a fresh request follows)."""
        pending, self._pending = self._pending, None
        self._taking = None if approached or pending is None else (*pending, pushed)

    def tick(self, t_ns: int, state, safety: SafetyInputs, live: Guard, setpoint: np.ndarray, live_events,
             driving: bool, fed: ActionChunk | None) -> None:
        """One tick beside the live guard's (``Run.tick_observer``): the candidate's answer taken on it pushed, its
        guard ticked on the live inputs, and the gap and the interventions that are its own put on the chunk it
        follows. While a recovery drives (no request is made), its chunks (``fed``) go into the shadow guard as
        into the live one, counted for no candidate chunk: the live guard goes on from them, so does the shadow's."""
        self._follow(live, t_ns, state)
        guard, taking, self._taking = self.guard, self._taking, None
        if driving:
            self._open = None
            if fed is not None:
                guard.push(fed, t_ns)
        elif taking is not None:
            row, candidate, pushed = taking
            self._open = row
            if not guard.power and live.power:  # its own stop removed power, not the live guard's: reset on the
                guard.reset(state.q)  # measured state (with the live one unpowered it holds as that does: ``_follow``)
            if candidate is not None:  # one the guard refuses (NaN, another action dimension) is its rejection
                self._note(row, guard.push(candidate, t_ns), live, pushed)
        if safety.asked_by in _INCUMBENTS:
            safety = self.cell.safety()
        own, events = guard.tick(t_ns, state, safety)
        self._live_power = live.power
        row = self._open
        if row is None:
            return
        gap = float(np.abs(own - setpoint).max())
        gap = gap if gap == gap else float("inf")  # NaN anywhere
        row["command_distance_rad"] = max(row["command_distance_rad"] or 0.0, gap)
        if events:
            self._note(row, events, live, live_events)
        if guard.envelope.scale < 1.0 and live.envelope.scale == 1.0 and SPEED_SCALED not in row["events"]:
            row["events"].append(SPEED_SCALED)
            row["clamped"] = True
        self._watchdog(t_ns, row)

    def _follow(self, live: Guard, t_ns: int, state) -> None:
        """A new shadow guard where the live one starts anew: built after the approach (at its reference, where the
        approach left the robot), reset with it after a stop removed its power (at its measured pose). The chunk it
        followed has its span end there; its own first-chunk watchdog runs again, as the loop's."""
        if live is not self._live:
            first, self._live = self._live is None, live
            if not first:  # the first: built already, at rest where the live guard is (its cell not measured again)
                self.guard, self._open = build_guard(self.cell, self.config, q0=live.reference), None
        elif live.power and not self._live_power:
            self.guard.reset(state.q)  # the state the live guard was reset on, read again
            self._open = None
        else:
            return
        self._live_power = live.power
        if not self._told:
            self._first_chunk_by = t_ns + self._watchdog_ns

    def _watchdog(self, t_ns: int, row: dict) -> None:
        """The loop's no-first-chunk watchdog, for the shadow guard: once a run, on the chunk it follows."""
        if self._first_chunk_by is None:
            return
        if self.guard.executor.last_chunk_ns is not None:
            self._first_chunk_by = None  # a first chunk was taken: the guard's own watchdog takes over
        elif t_ns > self._first_chunk_by:
            self._first_chunk_by, self._told = None, True
            row["events"].append(EventKind.WATCHDOG_NO_FIRST_CHUNK.value)
            row["stopped"] = True

    @staticmethod
    def _note(row: dict, events, live: Guard, live_events) -> None:
        """The shadow guard's interventions that are the candidate's: not a chunk that ran out (the policy's timing),
        not one the live guard made on the same tick for the same reason, not a speed condition the live guard slows
        for too (its slowing is counted as such in ``tick``)."""
        same = {(e.kind, e.reason, e.joint) for e in live_events} if live_events else ()
        for e in events:
            if e.kind in NO_INTERVENTION or (e.kind, e.reason, e.joint) in same:
                continue
            if e.kind in _SLOWING and live.envelope.scale < 1.0:
                continue
            row["events"].append(e.kind)
            if e.category is not None:
                row["stopped"] = True
            else:
                row["clamped"] = True


def _distance(a, b) -> float | None:
    """Max |a - b| over joints at a's steps (``ActionChunk.step_times_ns``) that b covers [rad]; NaN anywhere
    is infinite; None when they share no step (the candidate answered for another time), when b has no step
    period or another action dimension than a (its guard refuses it: an event), or when the incumbent's
    answer is no chunk (its own failure is the run's event)."""
    if not isinstance(a, ActionChunk) or np.shape(a.actions)[1:] != np.shape(b.actions)[1:] or not b.dt_ns > 0:
        return None
    worst = None
    for k, t_ns in enumerate(a.step_times_ns()):
        other = action_at(b, int(t_ns))
        if other is None:
            continue
        d = np.abs(np.asarray(a.actions[k]) - other)
        worst = max(worst or 0.0, float(d.max()) if np.all(np.isfinite(d)) else float("inf"))
    return worst


def _built_unseen(candidate: str, cell, soft_margin: float):
    """The candidate's policy, built without a trace in the live run: a simulated cell's noise generator is put back
    as it was (an ONNX adapter observes the cell to learn its inputs: two draws of camera noise, and every
    measurement of the incumbent's run after them differed from the run without a shadow)."""
    rng = getattr(cell, "rng", None)
    state = None if rng is None else rng.bit_generator.state
    policy = make_policy(candidate, cell, soft_margin=soft_margin)
    if rng is not None:
        rng.bit_generator.state = state
    return policy


class ShadowRun(Run):
    """A run of the incumbent (``scenario.policy``) with ``candidate`` in shadow mode."""

    def __init__(self, scenario: Scenario, candidate: str, candidate_guard: GuardConfig):
        if scenario.realtime.inference == "process":  # the process would run the incumbent alone
            raise ConfigError("shadow mode runs the candidate beside the incumbent in the loop's process: "
                              "realtime.inference must be 'thread'")
        super().__init__(scenario)
        try:  # at rest where the live guard is: measured again, a draw of the cell's noise changed the live run
            shadow_guard = build_guard(self.cell, candidate_guard, q0=self.guard.reference)
            candidate_policy = _built_unseen(candidate, self.cell, candidate_guard.soft_margin)
            self.policy = ShadowedPolicy(self.policy, candidate_policy, self.cell, candidate_guard, shadow_guard,
                                         lambda: self.cycles.total)
            self.tick_observer = self.policy.tick
        except BaseException:  # the incumbent's policy and a bridge are open: close them
            self.close()
            raise

    def _arrived(self, arrival, t_ns: int) -> bool:
        """The loop's; the candidate's answer is taken on the same tick (``ShadowedPolicy.taken``) with the events
        the live side raised taking the incumbent's (read by index: the log's window is not walked on the tick)."""
        events, before = self.events, self.events.total
        approached = super()._arrived(arrival, t_ns)
        self.policy.taken(approached, [events[i] for i in range(before, events.total)])
        return approached

    def write_shadow(self, folder: Path) -> str:
        """``shadow.json`` beside the record, written to a temporary name and renamed (atomic); the sha256 of what
        was written, which the run's row keeps (``evidence.counted_run`` reads only that file as its shadow)."""
        rows = [{**r, **{k: 1e9 for k in DISTANCES if r[k] is not None and not np.isfinite(r[k])}}
                for r in self.policy.rows]
        data = json.dumps({"candidate": self.policy.candidate.source, "chunks": rows}).encode()
        write_output(Path(folder) / SHADOW_FILE, data, "shadow record")
        return hashlib.sha256(data).hexdigest()
