"""The report's "What changed, in the order it began" dates each feature by its step, not by its CUSUM's
change point, which a noise dip before the step put cycles early (probe 41: a fixture shift at 14, its
fiducial dated 11)."""

from __future__ import annotations

import numpy as np
from test_diagnosis_rules import GEOMETRY

from cellguard.diagnose import diagnose


def test_a_feature_with_noise_before_its_step_is_dated_at_the_step():
    rng = np.random.default_rng(3)
    rows = []
    for i in range(40):
        f = {k: v + 0.02 * rng.standard_normal() for k, v in {**GEOMETRY, "place_error_mm": 0.5}.items()}
        if i in (30, 31):  # noise before the step, 2 scales high
            f["part_seen_y_mm"] += 0.1
            f["grasp_tcp_y_mm"] += 0.1
        if i >= 32:
            for k in ("part_seen_y_mm", "fixture_seen_y_mm", "grasp_tcp_y_mm"):
                f[k] += 1.0
        rows.append({"cycle": i, "phase": "acceptance" if i < 20 else "production", "success": True, "features": f})
    d = diagnose(rows, [], {})
    assert {a.onset for a in d.drift.alarms if a.signal == "part_seen_y_mm"} == {30}  # what its CUSUM read
    assert [(f.cause, f.cycle) for f in d.findings] == [("fixture_shift", 32)]
    assert {c.signal: c.onset for c in d.changes}["part_seen_y_mm"] == 32
    assert min(c.onset for c in d.changes) == 32
