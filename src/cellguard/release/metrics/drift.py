"""The diagnosis's drift alarms, each run against its own acceptance cycles."""

from __future__ import annotations

from cellguard.diagnose.diagnosis import diagnose
from cellguard.errors import CellguardError
from cellguard.release.metrics import Measure, Metric


def drift_alarms(runs) -> Measure:
    """Alarms of the diagnosis (CUSUM/MEWMA against the run's own acceptance cycles)."""
    count, n, ev = 0, 0, []
    for r in runs:
        d = r.once("drift", _diagnosed)
        if d is None:  # too few acceptance cycles for a baseline: this run gives no data
            continue
        n += sum(c.phase != "acceptance" for c in r.cycles)
        count += len(d["alarms"])
        ev += [f"{r.label(cycle)}: {signal} (statistic {stat:.1f})" for cycle, signal, stat in d["alarms"][:5]]
        ev += [f"{r.label(cycle)}: probable cause {cause}" for cycle, cause in d["causes"]]
    return Measure(float(count) if n else None, n, tuple(ev))


def _diagnosed(run) -> dict | None:
    """The run's alarms and first three probable causes, as kept with its evidence (a run is diagnosed once, not at
    every evaluation that counts it); None: too few acceptance cycles for a baseline."""
    try:
        d = diagnose(run.cycles, run.events, run.context)
    except CellguardError:
        return None
    return {"alarms": [[int(a.cycle), a.signal, float(a.statistic)] for a in d.drift.alarms],
            "causes": [[int(f.cycle), f.cause] for f in d.findings[:3]]}


METRICS = (Metric("drift_alarms", "", drift_alarms),)
