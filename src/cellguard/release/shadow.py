"""Shadow mode: the candidate answers the live observations next to the incumbent, never actuating.

The incumbent keeps driving. Each time it is asked for a chunk, the candidate is asked the same
observation; its chunk goes into a guard of its own (``cellguard.control.guard.Guard``, built
with the candidate's envelope settings) on the tick the loop takes the incumbent's, ticked on the
same servo clock but never writing to the robot. Per candidate chunk we keep the distance from what
its guard sends to what the incumbent's sent, max over joints as the next chunk is taken [rad] (the
raw chunks, kept as ``chunk_distance_rad``, read 0 for a candidate its own envelope slowed to a
crawl: a tool-speed cap of 0.25 m/s that failed every cycle), and whether its guard clamped it (a
limit intervention, or its playback slowed by a speed cap: no event, live or here) or stopped it
(a stop of any category) before the next chunk came. The loop's watchdog before the first chunk
lives in the loop, not in a guard, so the shadow keeps its own: a candidate whose chunks the guard
never takes (every one NaN) would be stopped live within ``watchdog_s`` (it counted 0 stops).
Written to ``shadow.json`` beside the record.
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
from cellguard.runtime import Run
from cellguard.scenario import Scenario

SPEED_SCALED = "speed_scaled"  # a row's note: the candidate's envelope slowed its playback (no guard event)
DISTANCES = ("distance_rad", "chunk_distance_rad")  # a row's [rad], written 1e9 where infinite (JSON has no inf)


class ShadowedPolicy:
    """The incumbent behind the Policy protocol, with the candidate computed beside it."""

    def __init__(self, incumbent, candidate, guard: Guard, dt_ns: int, cycle, watchdog_s: float):
        self.incumbent, self.candidate, self.guard, self.dt_ns, self.cycle = incumbent, candidate, guard, dt_ns, cycle
        self._following: dict | None = None  # the row of the candidate's last answer comparable with the incumbent's
        self._pending: tuple[dict, ActionChunk] | None = None  # the candidate's answer, till the loop takes its own
        self._taken: tuple[int, np.ndarray | None] | None = None  # (tick, the live setpoint before it): ``taken``
        self._setpoint: np.ndarray | None = None  # the shadow guard's last setpoint (D,) [rad]
        self.source = incumbent.source
        self.map_document = getattr(incumbent, "map_document", None)  # the record's map is the incumbent's
        self.rows: list[dict] = []
        self._open: dict | None = None  # the candidate chunk now in the shadow guard
        self._t_ns: int | None = None  # the shadow guard's next tick
        self._first_chunk_by: int | None = None  # the shadow's start plus the watchdog [ns]; None once checked
        self._watchdog_ns = round(watchdog_s * 1e9)

    def content_hash(self) -> str:
        return self.incumbent.content_hash()

    def reset(self) -> None:
        self.incumbent.reset()
        self.candidate.reset()

    def infer(self, observation):
        chunk = self.incumbent.infer(observation)  # what drives; a failure here is the run's event
        self._hand_over()
        self._advance(observation.t_ns)
        row = {"t_ns": int(observation.t_ns), "cycle": int(self.cycle()), "distance_rad": None,
               "chunk_distance_rad": None, "events": [], "clamped": False, "stopped": False}
        if not self.guard.power:  # the candidate's guard stopped with power removed: reset it on the live state
            self.guard.reset(observation.q)
        self._pending = None  # an answer the loop dropped (a new cycle's start) goes with the incumbent's
        try:  # the whole candidate side: whatever it answers, it never fails the incumbent's inference
            candidate = self.candidate.infer(observation)
            if not isinstance(candidate, ActionChunk):
                raise TypeError(f"the candidate answered {type(candidate).__name__}, not an ActionChunk")
            row["chunk_distance_rad"] = _distance(chunk, candidate)
            self._pending = row, candidate
        except Exception as exc:  # noqa: BLE001 - a failing candidate is a would-be stop, never the incumbent's
            row.update(events=[f"inference_failed: {type(exc).__name__}"], stopped=True)
            self._open = row
        self.rows.append(row)
        return chunk

    def taken(self, t_ns: int, sent: np.ndarray | None) -> None:
        """The loop took the incumbent's answer at tick ``t_ns``, ``sent`` (D,) [rad] the setpoint it sent the tick
        before (None before the first). Only noted here, on the servo thread: the next ``infer`` (an inference
        thread on wall time) pushes the candidate's answer at that tick, its guard ticked up to it first."""
        self._taken = t_ns, None if sent is None else np.array(sent, dtype=np.float64)

    def finish(self) -> None:
        """The run's end: the candidate's last answer goes into its guard too, on the tick the loop took the
        incumbent's or, where it never did, the shadow's next (a refusal is its event all the same)."""
        if self._pending is not None and self._taken is None and self._t_ns is not None:
            self._taken = self._t_ns, None
        self._hand_over()

    def _hand_over(self) -> None:
        """The candidate's answer into its guard on the tick the loop took the incumbent's, as the loop would hand it
        over (one the guard refuses, such as NaN or another action dimension, is its rejection, and a stop once the
        guard's watchdog runs out, as live). The answer before it gets its distance: what its guard sent then
        against what the incumbent's sent (None for an answer not comparable with the incumbent's, such as another
        action dimension: its refusal is the event)."""
        taken, self._taken = self._taken, None
        if taken is None or self._pending is None:
            return
        (t_ns, sent), (row, candidate) = taken, self._pending
        self._pending = None
        self._advance(t_ns)
        if self._following is not None and self._setpoint is not None:
            self._following["distance_rad"] = _gap(self._setpoint, sent)
        self._open = row
        self._note(row, self.guard.push(candidate, t_ns))
        self._following = row if row["chunk_distance_rad"] is not None else None  # comparable: measured when it ends

    def restart(self, guard: Guard) -> None:
        """The loop played an approach (the run's start) and built its guard where it left the robot: the shadow's
        starts there too (``guard``), its clock and first-chunk watchdog from the next tick it sees."""
        self.guard, self._t_ns, self._pending, self._taken, self._following = guard, None, None, None, None
        self._setpoint = None

    def _advance(self, t_ns: int) -> None:
        """Tick the shadow guard up to ``t_ns``; its events and slowing belong to the candidate chunk it follows."""
        if self._t_ns is None:
            self._t_ns, self._first_chunk_by = t_ns, t_ns + self._watchdog_ns
        guard, row = self.guard, self._open
        slowed = row is not None and SPEED_SCALED in row["events"]
        while self._t_ns < t_ns:
            self._setpoint, events = guard.tick(self._t_ns)
            if row is not None:
                if events:
                    self._note(row, events)
                if not slowed and guard.envelope.scale < 1.0:  # its playback slowed: no event, yet not its chunk
                    slowed = row["clamped"] = True
                    row["events"].append(SPEED_SCALED)
            self._t_ns += self.dt_ns
        if self._first_chunk_by is not None and guard.executor.last_chunk_ns is not None:
            self._first_chunk_by = None  # a first chunk was taken: the guard's own watchdog takes over
        elif self._first_chunk_by is not None and t_ns > self._first_chunk_by and row is not None:
            self._first_chunk_by = None  # once, as the loop's event is once
            row["events"].append(EventKind.WATCHDOG_NO_FIRST_CHUNK.value)
            row["stopped"] = True

    @staticmethod
    def _note(row: dict, events) -> None:
        for e in events:
            if e.kind in NO_INTERVENTION:  # a candidate chunk that ran out is no clamp of the envelope's
                continue
            row["events"].append(e.kind)
            if e.category is not None:
                row["stopped"] = True
            else:
                row["clamped"] = True


def _distance(a, b) -> float | None:
    """The raw chunks apart, kept beside the commands' distance to tell a candidate that asks for other motion from
    one its envelope changes: max |a - b| over joints at a's steps (``ActionChunk.step_times_ns``) that b covers
    [rad]; NaN anywhere is infinite; None when they share no step (the candidate answered for another time), when b
    has no step period or another action dimension than a (its guard refuses it: an event), or when the incumbent's
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


def _gap(setpoint: np.ndarray, sent: np.ndarray | None) -> float | None:
    """Max |setpoint - sent| over joints [rad]; NaN anywhere is infinite; None before the incumbent sent any."""
    if sent is None:
        return None
    d = float(np.abs(setpoint - sent).max())
    return d if np.isfinite(d) else float("inf")


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
        self._candidate_guard = candidate_guard
        try:  # at rest where the live guard is: measured again, a draw of the cell's noise changed the live run
            shadow_guard = build_guard(self.cell, candidate_guard, q0=self.guard.reference)
            candidate_policy = _built_unseen(candidate, self.cell, candidate_guard.soft_margin)
            self.policy = ShadowedPolicy(self.policy, candidate_policy, shadow_guard,
                                         self.cell.dt_ns, lambda: self.cycles.total, candidate_guard.watchdog_s)
        except BaseException:  # the incumbent's policy and a bridge are open: close them
            self.close()
            raise

    def _arrived(self, arrival, t_ns: int) -> bool:
        """The loop's, then the tick it took the incumbent's answer on noted for the candidate's
        (``ShadowedPolicy.taken``); after an approach the shadow guard is built anew where the live one is."""
        approached = super()._arrived(arrival, t_ns)
        if approached:
            self.policy.restart(build_guard(self.cell, self._candidate_guard, q0=self.guard.reference))
        else:
            self.policy.taken(t_ns, self.link.last_sent)
        return approached

    def write_shadow(self, folder: Path) -> str:
        """``shadow.json`` beside the record, written to a temporary name and renamed (atomic); the sha256 of what
        was written, which the run's row keeps (``evidence.counted_run`` reads only that file as its shadow)."""
        self.policy.finish()
        rows = [{**r, **{k: 1e9 for k in DISTANCES if r[k] is not None and not np.isfinite(r[k])}}
                for r in self.policy.rows]
        data = json.dumps({"candidate": self.policy.candidate.source, "chunks": rows}).encode()
        write_output(Path(folder) / SHADOW_FILE, data, "shadow record")
        return hashlib.sha256(data).hexdigest()
