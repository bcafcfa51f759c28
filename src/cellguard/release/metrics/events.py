"""What the guard did: its interventions and stops, and the ticks outside the profile's limits."""

from __future__ import annotations

from cellguard.control.checks.safety_input import ASKED_BY_LOOP, RECOVERY_HOLD
from cellguard.control.events import NO_INTERVENTION
from cellguard.release.evidence import RunEvidence
from cellguard.release.metrics import Measure, Metric, cycles_in


def interventions_per_hour(runs) -> Measure:
    """Envelope and executor events, not routine ones, per hour of cycles."""
    hours = sum(c.t_end_ns - c.t_start_ns for r in runs for c in r.cycles) / 3.6e12
    found = [(r.label(e.cycle), e.kind) for r in runs for e in r.events if e.kind not in NO_INTERVENTION]
    ev = tuple(f"{where}: {kind}" for where, kind in found[:10])
    return Measure(len(found) / hours if hours else None, cycles_in(runs), ev)


def protective_stops(runs) -> Measure:
    """Stop events of any category, each stop once (``_stops``)."""
    stops = [f"{r.label(e.cycle)}: {e.kind} (category {e.category}): {e.reason}" for r in runs for e in _stops(r)]
    return Measure(float(len(stops)), cycles_in(runs), tuple(stops[:10]))


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
    return Measure(float(sum(r.limits.count for r in runs)), cycles_in(runs), ev)


METRICS = (
    Metric("interventions_per_hour", "1/h", interventions_per_hour),
    Metric("protective_stops", "", protective_stops, hard=True),
    Metric("limit_violations", "", limit_violations, hard=True),
)
