"""Gate metrics, each computed from a stage's run records; one registry, one small function each.

A metric returns ``Measure(value, cycles, evidence)``: ``cycles`` is how much data it saw (a
gate with fewer than ``min_cycles`` is inconclusive), ``evidence`` names the records and cycles
that made the value what it is (a failed cycle, a stop, the worst seam). ``value`` is None when
the runs hold nothing to measure (no shadow data, no acceptance baseline). A metric that only some cells
or only shadow runs can report says so (``needs``, ``shadow``): a gate on it elsewhere could only end
inconclusive, so a plan's stage holding one is refused before it runs.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from cellguard.control.checks.safety_input import ASKED_BY_LOOP, RECOVERY_HOLD
from cellguard.control.events import NO_INTERVENTION
from cellguard.diagnose.diagnosis import diagnose
from cellguard.errors import CellguardError
from cellguard.release.evidence import RunEvidence
from cellguard.robot.pick_place import PickPlaceCell


@dataclass(frozen=True)
class Measure:
    value: float | None
    cycles: int
    evidence: tuple[str, ...] = ()


@dataclass(frozen=True)
class Needs:
    """What a cell must have for a metric to have any data: its cycles report what the metric reads."""

    what: str
    cell_type: type

    def met_by(self, cell) -> bool:
        return isinstance(cell, self.cell_type)


PICK_PLACE = Needs("a pick-place task (a part placed in a drop zone: its place error)", PickPlaceCell)


@dataclass(frozen=True)
class Metric:
    name: str
    unit: str
    compute: Callable[[Sequence[RunEvidence]], Measure]
    hard: bool = False  # a safety count: failure limit 0, decided even on too few cycles
    most: float = float("inf")  # the largest value it can take (every metric is at least 0)
    needs: Needs | None = None  # what the cell must have (None: every cell's runs give it data)
    shadow: bool = False  # measured on shadow runs only (a stage with ``shadow: true``)


def _n(runs) -> int:
    return sum(len(r.cycles) for r in runs)


def success_rate(runs) -> Measure:
    """Completed cycles that succeeded."""
    failed = [r.label(c.cycle) for r in runs for c in r.cycles if not c.success]
    n = _n(runs)
    return Measure(1.0 - len(failed) / n if n else None, n, tuple(f"{x}: failed" for x in failed[:10]))


def _percentile(runs, values: list[tuple[float, str]], q: float, unit: str) -> Measure:
    vals = [(v, where) for v, where in values if np.isfinite(v)]
    if not vals:
        return Measure(None, 0)
    x = np.array([v for v, _ in vals])
    worst = max(vals)
    return Measure(float(np.percentile(x, q)), _n(runs), (f"worst {worst[0]:.3g} {unit} in {worst[1]}",))


def cycle_time_p95(runs) -> Measure:
    return _percentile(runs, [((c.t_end_ns - c.t_start_ns) * 1e-9, r.label(c.cycle)) for r in runs for c in r.cycles],
                       95, "s")


def place_error_p95(runs) -> Measure:
    """Successful cycles' place error, p95 [mm]."""
    return _percentile(runs, [(c.features.get("place_error_mm", np.nan), r.label(c.cycle))
                              for r in runs for c in r.cycles if c.success], 95, "mm")


def interventions_per_hour(runs) -> Measure:
    """Envelope and executor events, not routine ones, per hour of cycles."""
    hours = sum(c.t_end_ns - c.t_start_ns for r in runs for c in r.cycles) / 3.6e12
    found = [(r.label(e.cycle), e.kind) for r in runs for e in r.events if e.kind not in NO_INTERVENTION]
    ev = tuple(f"{where}: {kind}" for where, kind in found[:10])
    return Measure(len(found) / hours if hours else None, _n(runs), ev)


def protective_stops(runs) -> Measure:
    """Stop events of any category, each stop once (``_stops``)."""
    stops = [f"{r.label(e.cycle)}: {e.kind} (category {e.category}): {e.reason}" for r in runs for e in _stops(r)]
    return Measure(float(len(stops)), _n(runs), tuple(stops[:10]))


def _stops(run: RunEvidence):
    """Stop events of any category, each stop once: the guard's protective stop that carries out a stop the loop
    asked for (operator stop, robot link fault, no first chunk) goes with the loop's own event before it in its
    cycle; one with no such event (a recovery's hand-over hold) counts."""
    causes = [e for e in run.events if e.category is not None and e.kind != "protective_stop"]
    for e in run.events:
        if e.category is None:
            continue
        if (e.kind == "protective_stop" and e.reason.startswith(ASKED_BY_LOOP)
                and e.reason != ASKED_BY_LOOP + RECOVERY_HOLD  # after a link fault in its cycle, still a stop
                and any(c.cycle == e.cycle and c.t_ns <= e.t_ns for c in causes)):
            continue
        yield e


def limit_violations(runs) -> Measure:
    """Measured joint positions outside the profile's range or speeds over its limit (the decimated
    ticks: 50 Hz on the arm)."""
    ev = tuple(f"{r.label(r.limits.first_cycle)}: {r.limits.joint} outside its limits ({r.limits.count} ticks)"
               for r in runs if r.limits.count)
    return Measure(float(sum(r.limits.count for r in runs)), _n(runs), ev)


def drift_alarms(runs) -> Measure:
    """Alarms of the diagnosis (CUSUM/MEWMA against the run's own acceptance cycles)."""
    count, n, ev = 0, 0, []
    for r in runs:
        try:
            d = diagnose(r.cycles, r.events, r.context)
        except CellguardError:  # too few acceptance cycles for a baseline: this run gives no data
            continue
        n += sum(c.phase != "acceptance" for c in r.cycles)
        count += len(d.drift.alarms)
        ev += [f"{r.label(a.cycle)}: {a.signal} (statistic {a.statistic:.1f})" for a in d.drift.alarms[:5]]
        ev += [f"{r.label(f.cycle)}: probable cause {f.cause}" for f in d.findings[:3]]
    return Measure(float(count) if n else None, n, tuple(ev))


def chunk_seam_jump_max(runs) -> Measure:
    """Largest step between the outgoing and incoming chunk at each switch [mrad], as received
    (``reductions.reduce_chunks``)."""
    stepped = [r for r in runs if r.chunks.worst_seam_t_ns is not None]
    worst = max(stepped, key=lambda r: r.chunks.worst_seam_mrad, default=None)
    ev = (f"largest seam {worst.chunks.worst_seam_mrad:.1f} mrad in {worst.label()} at "
          f"t={worst.chunks.worst_seam_t_ns * 1e-9:.3f} s",) if worst else ()
    seams = sum(r.chunks.seams for r in runs)
    return Measure(worst.chunks.worst_seam_mrad if worst else 0.0, _n(runs), ev) if seams else Measure(None, _n(runs))


def inference_latency_p99(runs) -> Measure:
    """Observation-to-chunk latency the loop applied, p99 over chunks [ms]."""
    have = [r for r in runs if len(r.chunks.latency_ms)]
    if not have:
        return Measure(None, 0)
    worst = max(have, key=lambda r: (r.chunks.latency_ms.max(), r.label()))  # a tie: the last label, as ever
    value = float(np.percentile(np.concatenate([r.chunks.latency_ms for r in have]), 99))
    return Measure(value, _n(runs), (f"worst {worst.chunks.latency_ms.max():.3g} ms in {worst.label()}",))


def _shadow(runs) -> list[tuple[dict, RunEvidence]]:
    return [(s, r) for r in runs for s in (r.shadow or ())]


def shadow_distance_p95(runs) -> Measure:
    """Candidate against incumbent per chunk: max joint distance over the shared steps, p95 [mrad]."""
    rows = [(s, r) for s, r in _shadow(runs) if s["distance_rad"] is not None]
    return _percentile(runs, [(s["distance_rad"] * 1e3, f"{r.label(s['cycle'])} chunk at t={s['t_ns'] * 1e-9:.3f} s")
                              for s, r in rows], 95, "mrad") if rows else Measure(None, 0)


def shadow_would_clamp(runs) -> Measure:
    """Fraction of the candidate's chunks the envelope would have clamped (a limit intervention)."""
    rows = _shadow(runs)
    hits = [f"{r.label(s['cycle'])} t={s['t_ns'] * 1e-9:.3f} s: {', '.join(s['events'])}" for s, r in rows if s["clamped"]]
    return Measure(len(hits) / len(rows) if rows else None, _n(runs) if rows else 0, tuple(hits[:10]))


def shadow_would_stop(runs) -> Measure:
    """Candidate chunks the envelope would have stopped (a stop event of any category)."""
    rows = _shadow(runs)
    hits = [f"{r.label(s['cycle'])} t={s['t_ns'] * 1e-9:.3f} s: {', '.join(s['events'])}" for s, r in rows if s["stopped"]]
    return Measure(float(len(hits)) if rows else None, _n(runs) if rows else 0, tuple(hits[:10]))


METRICS: dict[str, Metric] = {m.name: m for m in (
    Metric("success_rate", "", success_rate, most=1.0),
    Metric("cycle_time_p95_s", "s", cycle_time_p95),
    Metric("place_error_p95_mm", "mm", place_error_p95, needs=PICK_PLACE),
    Metric("interventions_per_hour", "1/h", interventions_per_hour),
    Metric("protective_stops", "", protective_stops, hard=True),
    Metric("limit_violations", "", limit_violations, hard=True),
    Metric("drift_alarms", "", drift_alarms),
    Metric("chunk_seam_jump_max_mrad", "mrad", chunk_seam_jump_max),
    Metric("inference_latency_p99_ms", "ms", inference_latency_p99),
    Metric("shadow_distance_p95_mrad", "mrad", shadow_distance_p95, shadow=True),
    Metric("shadow_would_clamp", "", shadow_would_clamp, most=1.0, shadow=True),
    Metric("shadow_would_stop", "", shadow_would_stop, hard=True, shadow=True),
)}
