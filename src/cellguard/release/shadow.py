"""Shadow mode: the candidate answers the live observations next to the incumbent, never actuating.

The incumbent keeps driving. Each time it is asked for a chunk, the candidate is asked the same
observation; its chunk goes into a guard of its own (``cellguard.control.guard.Guard``, built
with the candidate's envelope settings) that is ticked on the same servo clock but never writes
to the robot. Per candidate chunk we keep the distance to the incumbent's chunk (max over joints
and shared steps [rad]) and whether its guard clamped it (a limit intervention) or stopped it
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


class ShadowedPolicy:
    """The incumbent behind the Policy protocol, with the candidate computed beside it."""

    def __init__(self, incumbent, candidate, guard: Guard, dt_ns: int, cycle, watchdog_s: float):
        self.incumbent, self.candidate, self.guard, self.dt_ns, self.cycle = incumbent, candidate, guard, dt_ns, cycle
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
        self._advance(observation.t_ns)
        row = {"t_ns": int(observation.t_ns), "cycle": int(self.cycle()), "distance_rad": None, "events": [],
               "clamped": False, "stopped": False}
        if not self.guard.power:  # the candidate's guard stopped with power removed: reset it on the live state
            self.guard.reset(observation.q)
        try:  # the whole candidate side: whatever it answers, it never fails the incumbent's inference
            self._take(row, chunk, self.candidate.infer(observation), observation.t_ns)
        except Exception as exc:  # noqa: BLE001 - a failing candidate is a would-be stop, never the incumbent's
            row.update(events=[f"inference_failed: {type(exc).__name__}"], stopped=True)
        self.rows.append(row)
        self._open = row
        return chunk

    def _take(self, row: dict, chunk, candidate, t_ns: int) -> None:
        """The candidate's answer into its guard as the loop hands a chunk over: no chunk at all is a failed
        inference; one the guard refuses (another action dimension, NaN, a bad step) is its rejection, and a
        stop once the guard's watchdog runs out, as it would be live."""
        if not isinstance(candidate, ActionChunk):
            raise TypeError(f"the candidate answered {type(candidate).__name__}, not an ActionChunk")
        row["distance_rad"] = _distance(chunk, candidate)
        self._note(row, self.guard.push(candidate, t_ns))

    def _advance(self, t_ns: int) -> None:
        """Tick the shadow guard up to ``t_ns``; its events belong to the candidate chunk it was following."""
        if self._t_ns is None:
            self._t_ns, self._first_chunk_by = t_ns, t_ns + self._watchdog_ns
        while self._t_ns < t_ns:
            _, events = self.guard.tick(self._t_ns)
            if events and self._open is not None:
                self._note(self._open, events)
            self._t_ns += self.dt_ns
        if self._first_chunk_by is not None and self.guard.executor.last_chunk_ns is not None:
            self._first_chunk_by = None  # a first chunk was taken: the guard's own watchdog takes over
        elif self._first_chunk_by is not None and t_ns > self._first_chunk_by and self._open is not None:
            self._first_chunk_by = None  # once, as the loop's event is once
            self._open["events"].append(EventKind.WATCHDOG_NO_FIRST_CHUNK.value)
            self._open["stopped"] = True

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
            self.policy = ShadowedPolicy(self.policy, candidate_policy, shadow_guard,
                                         self.cell.dt_ns, lambda: self.cycles.total, candidate_guard.watchdog_s)
        except BaseException:  # the incumbent's policy and a bridge are open: close them
            self.close()
            raise

    def write_shadow(self, folder: Path) -> str:
        """``shadow.json`` beside the record, written to a temporary name and renamed (atomic); the sha256 of what
        was written, which the run's row keeps (``evidence.counted_run`` reads only that file as its shadow)."""
        rows = [{**r, "distance_rad": r["distance_rad"] if r["distance_rad"] is None or np.isfinite(r["distance_rad"])
                 else 1e9} for r in self.policy.rows]
        data = json.dumps({"candidate": self.policy.candidate.source, "chunks": rows}).encode()
        write_output(Path(folder) / SHADOW_FILE, data, "shadow record")
        return hashlib.sha256(data).hexdigest()
