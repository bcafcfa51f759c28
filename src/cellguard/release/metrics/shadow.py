"""The pilot's shadow runs: the candidate against the incumbent, and what its own guard would have done."""

from __future__ import annotations

from cellguard.release.evidence import RunEvidence
from cellguard.release.metrics import Measure, Metric, cycles_in, percentile


def _shadow(runs) -> list[tuple[dict, RunEvidence]]:
    return [(s, r) for r in runs for s in (r.shadow or ())]


def _distance(row: dict) -> float | None:
    """A chunk's distance [rad]: between what the two guards commanded over its span (``command_distance_rad``),
    or in a file written before that was kept, the raw chunks' over their shared steps (``distance_rad``)."""
    return row["command_distance_rad"] if "command_distance_rad" in row else row["distance_rad"]


def shadow_distance_p95(runs) -> Measure:
    """Candidate against incumbent per chunk: max joint distance of the commands over its span, p95 [mrad]."""
    rows = [(d, s, r) for s, r in _shadow(runs) if (d := _distance(s)) is not None]
    return percentile(runs, [(d * 1e3, f"{r.label(s['cycle'])} chunk at t={s['t_ns'] * 1e-9:.3f} s")
                             for d, s, r in rows], 95, "mrad") if rows else Measure(None, 0)


def shadow_would_clamp(runs) -> Measure:
    """Fraction of the candidate's chunks its envelope would have clamped (a limit intervention, or its playback
    slowed where the live one's was not), the live guard's own interventions left out."""
    rows = _shadow(runs)
    hits = [f"{r.label(s['cycle'])} t={s['t_ns'] * 1e-9:.3f} s: {', '.join(s['events'])}" for s, r in rows if s["clamped"]]
    return Measure(len(hits) / len(rows) if rows else None, cycles_in(runs) if rows else 0, tuple(hits[:10]))


def shadow_would_stop(runs) -> Measure:
    """Candidate chunks the envelope would have stopped (a stop event of any category)."""
    rows = _shadow(runs)
    hits = [f"{r.label(s['cycle'])} t={s['t_ns'] * 1e-9:.3f} s: {', '.join(s['events'])}" for s, r in rows if s["stopped"]]
    return Measure(float(len(hits)) if rows else None, cycles_in(runs) if rows else 0, tuple(hits[:10]))


METRICS = (
    Metric("shadow_distance_p95_mrad", "mrad", shadow_distance_p95, shadow=True),
    Metric("shadow_would_clamp", "", shadow_would_clamp, most=1.0, shadow=True),
    Metric("shadow_would_stop", "", shadow_would_stop, hard=True, shadow=True),
)
