"""The side of a mirrored asymmetry names only its joints whose comparisons point to it (the others are said,
not named), and no side where only the motions differ (the yaw rate reached): a weaker servo makes its side's
turns overshoot on the quadruped and friction makes them fall short, so the yaw rate alone does not tell."""

from __future__ import annotations

import numpy as np

from cellguard.diagnose import as_cycles, diagnose, mirrored_asymmetry
from cellguard.embodiment.profile import SymmetryPair

J = (("fl_hip", "fr_hip"), ("fl_knee", "fr_knee"), ("rl_hip", "rr_hip"))
PAIRS = tuple(SymmetryPair(left, right, 1.0) for left, right in J)


def _rows(scale: dict[str, float], yaw: tuple[float, float] = (0.95, 0.95), n: int = 12, seed: int = 1) -> list[dict]:
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n):
        lab = "left" if i % 2 == 0 else "right"
        f = {f"tracking_rms.{j}": 0.01 * scale.get(j, 1.0) * (1 + 0.005 * rng.standard_normal()) for p in J for j in p}
        f["yaw_rate_ratio"] = yaw[lab == "right"] * (1 + 0.002 * rng.standard_normal())
        rows.append({"cycle": i, "phase": "production", "success": True, "direction": lab, "features": f})
    return rows


def test_a_joint_whose_comparison_points_to_the_other_side_is_not_named():
    """A weak left front leg (fl_hip, fl_knee 20 % worse) and rr_hip 15 % worse than rl_hip."""
    a = mirrored_asymmetry(as_cycles(_rows({"fl_hip": 1.2, "fl_knee": 1.2, "rr_hip": 1.15})), PAIRS)
    assert a.side == "left" and set(a.joints) == {"fl_hip", "fl_knee"}, (a.side, a.joints)
    assert "2 point to the right side, not named: tracking_rms.rl_hip" in a.evidence[0], a.evidence[0]


def test_only_the_yaw_rate_differing_names_no_side():
    for yaw in ((0.85, 0.95), (0.95, 0.85)):
        a = mirrored_asymmetry(as_cycles(_rows({}, yaw)), PAIRS)
        assert a.side is None and a.joints == () and len(a.significant) == 1, (yaw, a.side, a.evidence)
        assert "which side they do not tell" in a.evidence[0], a.evidence


def test_a_yaw_only_asymmetry_is_told_without_a_side():
    rows = _rows({}, (0.84, 0.96), n=24)
    for r in rows[:12]:
        r["phase"], r["features"]["yaw_rate_ratio"] = "acceptance", 0.96
    d = diagnose(rows, [], {}, symmetry=PAIRS)
    words = [e for f in d.findings for e in f.evidence if e.startswith("mirrored motions differ")]
    assert words == ["mirrored motions differ between the motions, on no side a joint or leg tells"], [
        f.to_dict() for f in d.findings]


def test_the_report_never_says_motions_that_differ_on_no_side_agree():
    """With no side to name, the report's verdict said "Mirrored motions agree." (before: "The right side differs")."""
    from cellguard.report.html import _asymmetry

    rows = _rows({}, (0.84, 0.96), n=24)
    for r in rows[:12]:
        r["phase"], r["features"]["yaw_rate_ratio"] = "acceptance", 0.96
    d = diagnose(rows, [], {}, symmetry=PAIRS)
    html = _asymmetry(d)
    assert "agree" not in html and "Mirrored motions differ between the motions" in html and "yaw_rate_ratio" in html
