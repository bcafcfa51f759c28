"""The diagnosis's drift alarms, each run against its own acceptance cycles."""

from __future__ import annotations

from cellguard.diagnose.diagnosis import diagnose
from cellguard.errors import CellguardError
from cellguard.release.metrics import Measure, Metric


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


METRICS = (Metric("drift_alarms", "", drift_alarms),)
