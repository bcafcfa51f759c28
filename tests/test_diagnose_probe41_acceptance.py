"""A fault that began inside the diagnosed record's own acceptance phase (probe 41): against another record's
acceptance every cycle is watched and the fault dated where it began; against its own acceptance the step
there is a warning (the baseline is not steady), which a steady acceptance never gives."""

from __future__ import annotations

import numpy as np
from test_diagnosis_rules import SO101

from cellguard.diagnose import Baseline, as_cycles, diagnose


def _rows(at: int | None, seed: int, acceptance: int = 10, n: int = 18) -> list[dict]:
    """SO-101 joints (0.2 % noise) whose elbow_flex tracking error steps +3 % from cycle ``at``."""
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n):
        f = {k: v * (1 + 2e-3 * rng.standard_normal()) for k, v in SO101.items()}
        if at is not None and i >= at:
            f["tracking_rms.elbow_flex"] *= 1.03
            f["tracking_max.elbow_flex"] *= 1.03
        rows.append({"cycle": i, "phase": "acceptance" if i < acceptance else "production", "success": True,
                     "features": f})
    return rows


def _elsewhere(seed: int = 1) -> Baseline:
    accepted = [c for c in as_cycles(_rows(None, seed)) if c.phase == "acceptance"]
    return Baseline.from_cycles(accepted, source="acceptance cycles of another record")


def test_against_another_records_acceptance_a_fault_in_this_ones_acceptance_is_dated_where_it_began():
    d = diagnose(_rows(5, seed=2), [], {}, baseline=_elsewhere())
    assert [(f.cause, f.cycle, f.joints) for f in d.findings] == [("servo", 5, ("elbow_flex",))]
    assert (d.last_good_cycle, d.first_faulted_cycle) == (4, 5)


def test_a_step_in_the_own_acceptance_makes_the_baseline_unsteady():
    d = diagnose(_rows(5, seed=2), [], {})
    assert sorted(d.baseline.trends) == ["tracking_max.elbow_flex", "tracking_rms.elbow_flex"]
    assert 0.025 < d.baseline.trends["tracking_rms.elbow_flex"] / SO101["tracking_rms.elbow_flex"] < 0.035


def test_a_steady_acceptance_reads_steady():
    for seed in range(20):
        assert Baseline.from_cycles([c for c in as_cycles(_rows(None, seed)) if c.phase == "acceptance"]).trends == {}
