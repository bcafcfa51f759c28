"""Last good versus faulted: the last cycle that did its task before the first finding against the first faulted one.

A technician's first check: put the last cycle that was still right next to the first one that
was not, and list what differs, in the order the changes began.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from cellguard.diagnose.baseline import Baseline
from cellguard.diagnose.cycles import Cycle
from cellguard.diagnose.drift import DriftAlarm


@dataclass(frozen=True)
class FeatureChange:
    """How one alarmed feature moved: onset and alarm cycles, values, and the change in scales."""

    signal: str
    onset: int
    alarm_cycle: int
    baseline: float  # of the alarm cycle's own motion
    last_good: float
    first_faulted: float
    at_alarm: float
    change: float  # at_alarm - baseline, in the feature's unit
    scales: float  # the same change in baseline scales

    def to_dict(self) -> dict:
        return {k: (round(v, 6) if isinstance(v, float) else v) for k, v in self.__dict__.items()}


def last_good_and_faulted(cycles: Sequence[Cycle], first_faulted: int | None) -> tuple[Cycle | None, Cycle | None]:
    """The last cycle before ``first_faulted`` that did its task, and the first at or after it. One that failed its
    task is not good, whatever the monitors made of it: a cell that missed every pick had its last failed cycle
    before the finding called last good; None where no earlier cycle succeeded."""
    if first_faulted is None:
        return None, None
    before = [c for c in cycles if c.index < first_faulted and c.success]
    after = [c for c in cycles if c.index >= first_faulted]
    return (before[-1] if before else None), (after[0] if after else None)


def changes(baseline: Baseline, alarms: Sequence[DriftAlarm], good: Cycle | None,
            faulted: Cycle | None, later: Sequence[Cycle],
            dated: Callable[[DriftAlarm], int] = lambda a: a.onset) -> list[FeatureChange]:
    """Every alarmed feature, earliest change first, each dated by ``dated`` (never before its finding, where the
    caller knows the findings: a CUSUM's change point wanders early with the noise); a feature missing in a cycle
    reads NaN.

    The change is read at the alarm's cycle (in ``later``): a ramp has barely moved in the first
    faulted cycle, and the technician wants to know how far it went.
    """
    out = []
    seen = set()
    for onset, a in sorted(((dated(a), a) for a in alarms), key=lambda t: (t[0], t[1].cycle, t[1].signal)):
        if a.signal == "multivariate" or a.signal in seen or a.signal not in baseline.names:
            continue
        seen.add(a.signal)
        at_alarm = next((c for c in later if c.index == a.cycle), faulted)
        j = baseline.names.index(a.signal)
        centre, scales = baseline.centre_and_scale([at_alarm]) if at_alarm else (None, None)
        median = float(centre[0, j]) if centre is not None else baseline.median(a.signal)
        scale = float(scales[0, j]) if scales is not None else baseline.scale(a.signal)
        g = good.features.get(a.signal, np.nan) if good else np.nan
        f = faulted.features.get(a.signal, np.nan) if faulted else np.nan
        v = at_alarm.features.get(a.signal, np.nan) if at_alarm else np.nan
        change = v - median
        out.append(FeatureChange(a.signal, onset, a.cycle, median, float(g), float(f), float(v),
                                 float(change), float(change / scale)))
    return out
