"""A step at the first watched cycle is dated there: the fit of its onset has the baseline before it
(a fault from the first production cycle on, or one present from the start of a record checked against
another run's acceptance), so the first failed cycle is never called the last good one."""

from __future__ import annotations

import numpy as np
from test_diagnosis_rules import GEOMETRY

from cellguard.diagnose import Baseline, as_cycles, diagnose


def _shifted(at: int, acceptance: int = 20, n: int = 30, seed: int = 5) -> list[dict]:
    """Geometry rows whose fixture (part, fiducial and grasp with it) moved 1 mm in y from cycle ``at`` on."""
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n):
        f = {k: v + 0.02 * rng.standard_normal() for k, v in {**GEOMETRY, "place_error_mm": 0.5}.items()}
        if i >= at:
            for k in ("part_seen_y_mm", "fixture_seen_y_mm", "grasp_tcp_y_mm"):
                f[k] += 1.0
        rows.append({"cycle": i, "phase": "acceptance" if i < acceptance else "production", "success": True,
                     "features": f})
    return rows


def test_a_shift_at_the_first_production_cycle_is_dated_there():
    d = diagnose(_shifted(at=20), [], {})
    assert [(f.cause, f.cycle) for f in d.findings] == [("fixture_shift", 20)], [f.to_dict() for f in d.findings]
    assert (d.last_good_cycle, d.first_faulted_cycle) == (19, 20)


def test_a_shift_one_cycle_later_is_still_dated_at_its_step():
    d = diagnose(_shifted(at=21), [], {})
    assert [(f.cause, f.cycle) for f in d.findings] == [("fixture_shift", 21)], [f.to_dict() for f in d.findings]


def test_a_shift_present_from_the_start_of_a_record_checked_against_another_acceptance_is_dated_at_its_start():
    accepted = as_cycles(_shifted(at=99, n=20))
    rows = _shifted(at=0, acceptance=0, n=10, seed=6)
    d = diagnose(rows, [], {}, baseline=Baseline.from_cycles(accepted))
    assert [(f.cause, f.cycle) for f in d.findings] == [("fixture_shift", 0)], [f.to_dict() for f in d.findings]
    assert (d.last_good_cycle, d.first_faulted_cycle) == (None, 0)
