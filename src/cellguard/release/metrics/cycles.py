"""What each cycle gives: its success, its time, where the part was placed."""

from __future__ import annotations

import numpy as np

from cellguard.release.metrics import PICK_PLACE, Measure, Metric, cycles_in, percentile


def success_rate(runs) -> Measure:
    """Completed cycles that succeeded."""
    failed = [r.label(c.cycle) for r in runs for c in r.cycles if not c.success]
    n = cycles_in(runs)
    return Measure(1.0 - len(failed) / n if n else None, n, tuple(f"{x}: failed" for x in failed[:10]))


def cycle_time_p95(runs) -> Measure:
    return percentile(runs, [((c.t_end_ns - c.t_start_ns) * 1e-9, r.label(c.cycle)) for r in runs for c in r.cycles],
                       95, "s")


def place_error_p95(runs) -> Measure:
    """Successful cycles' place error, p95 [mm]."""
    return percentile(runs, [(c.features.get("place_error_mm", np.nan), r.label(c.cycle))
                              for r in runs for c in r.cycles if c.success], 95, "mm")


METRICS = (
    Metric("success_rate", "", success_rate, most=1.0),
    Metric("cycle_time_p95_s", "s", cycle_time_p95),
    Metric("place_error_p95_mm", "mm", place_error_p95, needs=PICK_PLACE),
)
