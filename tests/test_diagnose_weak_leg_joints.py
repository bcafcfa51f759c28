"""A weak side's joint whose current rose with its tracking error (a weakened drive that also carries more
of the body) is one of the servo finding's joints, not compensation (fast: synthetic cycles; the quadruped
scenario's fl_abduction, current and tracking error +36 % each, was told as the other legs' share)."""

from __future__ import annotations

from test_diagnose_legs import PAIRS, _legged, _scale

from cellguard.diagnose import diagnose


def _weak_left(knee_error: float):
    """fl_hip, rl_hip and rl_knee track 10 % worse; fl_knee's current and tracking error rise together by
    ``knee_error``; the right legs' currents rise 8 % (they take the weak side's share)."""
    def change(f: dict) -> None:
        _scale(f, {f"{k}.{j}": 1.1 for k in ("tracking_rms", "tracking_max") for j in ("fl_hip", "rl_hip", "rl_knee")})
        _scale(f, {f"{k}.fl_knee": 1.0 + knee_error for k in ("current_rms", "current_peak", "tracking_rms",
                                                              "tracking_max")})
        _scale(f, {f"{k}.rr_{j}": 1.08 for k in ("current_rms", "current_peak") for j in ("hip", "knee")})
    return change


def test_a_weak_side_joint_tracking_as_badly_as_the_weak_ones_is_a_servo_joint_not_compensation():
    d = diagnose(_legged(_weak_left(0.2)), [], {}, symmetry=PAIRS)
    assert [(f.cause, f.joints, f.legs) for f in d.findings] == [
        ("servo", ("fl_hip", "fl_knee", "rl_hip", "rl_knee"), ("fl", "rl"))], [f.to_dict() for f in d.findings]
    evidence = d.findings[0].evidence
    assert "fl_knee: current +20.0 %, tracking error +20.0 % vs baseline" in evidence, evidence
    words = " ".join(evidence)
    assert "leg rr take its share of the body" in words and "weak leg itself" not in words, words
    assert {"tracking_rms.fl_knee", "current_rms.fl_knee"} <= set(d.findings[0].signals)


def test_a_weak_side_joint_whose_error_rose_less_than_the_weak_ones_stays_compensation():
    d = diagnose(_legged(_weak_left(0.05)), [], {}, symmetry=PAIRS)
    assert [(f.cause, f.joints) for f in d.findings] == [("servo", ("fl_hip", "rl_hip", "rl_knee"))], \
        [f.to_dict() for f in d.findings]
    assert "fl_knee on the weak leg itself among them" in " ".join(d.findings[0].evidence)
