"""Residual alarms on a robot on its feet that come with a weaker servo or a lasting policy latency are told in
that finding, not ``model_drift`` findings: a weak leg's servo shows a friction-like residual on its own joint
(its foot forces change), the other legs' joints alarm up to the monitor's latency later (its second window of
the same motion: 4 cycles on a cell that alternates two turns), and a latency's stale plan alarms as soon. Later
alarms are changes of their own: an elbow friction x1.5 six cycles into a lasting latency on the arm, told in it,
was lost; and a weak joint's friction that ROSE is no servo's evidence (a friction x3 the diagnosis misread as a
servo lost its re-fit advice)."""

from __future__ import annotations

import numpy as np

from cellguard.diagnose import diagnose
from cellguard.diagnose.cause import Finding
from cellguard.diagnose.residual import residual_alarms, with_residual


def _alarm(joint: str, parameter: str = "friction", change: float = -0.5) -> dict:
    return {"joint": joint, "parameter": parameter, "signature": parameter.split("/")[0], "change": change,
            "message": f"drifted at {joint}"}


def _rows(alarms: dict[int, list[dict]], legs: bool = True, n: int = 26) -> list[dict]:
    """Cycles alternating left and right turns (an arm's: one motion, no gait), with residual ``alarms`` per cycle."""
    rows = []
    for i in range(n):
        features = {"contact_duty.fr": 0.6, "current_rms.fr_knee": 2.0} if legs else {"current_rms.elbow": 2.0}
        rows.append({"cycle": i, "features": features, **({"direction": "left" if i % 2 == 0 else "right"}
                                                            if legs else {}),
                     "outcome": {"residual": {"signatures": ["friction", "inertia", "delay"],
                                              "alarms": alarms.get(i, [])}}})
    return rows


def _servo(joint: str = "fr_knee") -> Finding:
    return Finding("servo", 14, 0.95, (f"{joint}: current -2.4 %, tracking error +14.7 % vs baseline",
                                       "the servo gain dropped"), (f"tracking_rms.{joint}",), (joint,))


def test_a_friction_like_residual_on_a_weak_leg_s_joint_is_its_servo_s_evidence():
    merged = with_residual([_servo()], residual_alarms(_rows({15: [_alarm("fr_knee")]})))
    assert [f.cause for f in merged] == ["servo"], [f.to_dict() for f in merged]
    assert "residual.fr_knee.friction" in merged[0].signals
    assert "foot forces the model does not hold" in merged[0].evidence[-1], merged[0].evidence


def test_a_friction_that_rose_on_the_servo_s_joint_stays_its_own_finding():
    merged = with_residual([_servo()], residual_alarms(_rows({15: [_alarm("fr_knee", change=0.105)]})))
    assert [(f.cause, f.cycle) for f in merged] == [("servo", 14), ("model_drift", 15)], [f.to_dict() for f in merged]
    assert "identify DIR --only fr_knee,friction" in " ".join(merged[1].evidence)


def test_the_other_legs_alarms_up_to_the_monitor_s_latency_are_told_in_the_servo_finding():
    alarms = {15: [_alarm("rr_hip")], 17: [_alarm("fl_knee", "inertia/payload")]}
    merged = with_residual([_servo()], residual_alarms(_rows(alarms)))
    assert [f.cause for f in merged] == ["servo"], [f.to_dict() for f in merged]
    words = merged[0].evidence[-1]
    assert "residual monitor from cycle 15 at rr_hip, fl_knee" in words and "weak leg's share" in words, words
    assert {"residual.rr_hip.friction", "residual.fl_knee.inertia"} <= set(merged[0].signals)


def test_an_alarm_past_the_monitor_s_latency_or_on_an_arm_stays_a_model_drift():
    late = with_residual([_servo()], residual_alarms(_rows({21: [_alarm("rr_abduction")]})))
    assert [(f.cause, f.cycle) for f in late] == [("servo", 14), ("model_drift", 21)]
    arm = with_residual([_servo("elbow")], residual_alarms(_rows({15: [_alarm("elbow")]}, legs=False)))
    assert [f.cause for f in arm] == ["servo", "model_drift"]  # an arm's weaker servo leaves friction as it was


def _latency_record(back: int | None, alarm_at: int) -> list[dict]:
    """A quadruped-like record: 12 acceptance cycles, a policy latency of 160 ms from cycle 14 (back to 10 ms from
    ``back``), a residual alarm at fl_knee in cycle ``alarm_at``."""
    rng = np.random.default_rng(3)
    rows = []
    for i in range(30):
        late = 14 <= i and (back is None or i < back)
        f = {"latency_mean_ms": (160.0 if late else 10.0) + rng.normal(0, 0.3),
             "contact_duty.fl": 0.6 + rng.normal(0, 0.002), "current_rms.fl_knee": 2.0 + rng.normal(0, 0.01)}
        alarms = [_alarm("fl_knee", "inertia/payload")] if i == alarm_at else []
        rows.append({"cycle": i, "phase": "acceptance" if i < 12 else "production", "success": True,
                     "direction": "left" if i % 2 == 0 else "right", "features": f,
                     "outcome": {"residual": {"signatures": ["friction", "inertia", "delay"], "alarms": alarms}}})
    return rows


def test_alarms_up_to_the_monitor_s_latency_after_a_latency_began_are_told_in_it():
    d = diagnose(_latency_record(None, 18), [], {})
    assert [f.cause for f in d.findings] == ["policy_latency"], [f.to_dict() for f in d.findings]
    assert "residual monitor from cycle 18 at fl_knee" in " ".join(d.findings[0].evidence)


def test_an_alarm_later_in_a_lasting_latency_is_a_change_of_its_own():
    d = diagnose(_latency_record(None, 23), [], {})
    assert [(f.cause, f.cycle) for f in d.findings] == [("policy_latency", 14), ("model_drift", 23)], [
        f.to_dict() for f in d.findings]


def test_an_alarm_long_after_a_latency_ended_is_a_model_drift():
    d = diagnose(_latency_record(17, 25), [], {})
    assert [(f.cause, f.cycle) for f in d.findings] == [("policy_latency", 14), ("model_drift", 25)], [
        f.to_dict() for f in d.findings]
    assert "back to" in d.findings[0].evidence[0]  # the latency was read to have ended
