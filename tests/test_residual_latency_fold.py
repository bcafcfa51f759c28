"""Residual alarms that arrive with a policy latency are the stale plan's motion, told in the latency
finding, not a model drift per joint; and a model drift's re-fit advice is one its cell can follow (a
robot on its feet is excited on a stand; no payload where the model has none)."""

from __future__ import annotations

from cellguard.diagnose.cause import Finding
from cellguard.diagnose.residual import residual_alarms, with_residual

LEGS = ("fl_hip", "fr_knee", "rl_abduction")


def _alarm(joint: str, cycle: int, parameter: str = "friction") -> dict:
    return {"cycle": cycle, "joint": joint, "parameter": parameter, "signature": parameter.split("/")[0],
            "message": f"drifted at {joint}"}


def _latency(cycle: int = 12) -> Finding:
    return Finding("policy_latency", cycle, 0.95, ("policy latency 210 ms per chunk vs 10 ms at acceptance",
                                                  "late chunks answer old observations"), ("latency_mean_ms",))


def test_alarms_that_arrive_with_a_latency_are_told_in_it_not_model_drift():
    alarms = [_alarm(j, 13 + (j == "rl_abduction"), p)
              for j, p in zip(LEGS, ("friction", "inertia/payload", "delay"), strict=True)]
    merged = with_residual([_latency()], alarms)
    assert [f.cause for f in merged] == ["policy_latency"], [f.to_dict() for f in merged]
    words = merged[0].evidence[-1]
    assert "residual monitor from cycle 13 at fl_hip, fr_knee, rl_abduction" in words, words
    assert "stale plan" in words
    assert {"residual.fl_hip.friction", "residual.fr_knee.inertia", "residual.rl_abduction.delay"} <= set(
        merged[0].signals)


def test_an_alarm_long_after_the_latency_is_still_a_model_drift():
    merged = with_residual([_latency()], [_alarm("fl_hip", 20)])
    assert [(f.cause, f.cycle) for f in merged] == [("policy_latency", 12), ("model_drift", 20)]


def _row(cycle: int, alarm: dict, signatures: list[str], features: dict) -> dict:
    return {"cycle": cycle, "features": features,
            "outcome": {"residual": {"signatures": signatures, "alarms": [alarm]}}}


def test_a_legged_robot_s_model_drift_advises_a_stand_and_no_payload():
    row = _row(13, _alarm("fl_knee", 13, "inertia/payload"), ["friction", "inertia", "delay"],
               {"contact_duty.fl": 0.6, "current_rms.fl_knee": 2.0})
    (drift,) = with_residual([], residual_alarms([row]))
    advice = drift.evidence[1]
    assert "`cellguard excite CELL --stand --seconds 20 --out DIR`" in advice, advice
    assert "`cellguard identify DIR --only fl_knee,armature`" in advice and "payload`" not in advice, advice


def test_an_arm_s_model_drift_offers_payload_and_no_stand():
    row = _row(13, _alarm("elbow", 13, "inertia/payload"), ["friction", "inertia", "payload", "delay"],
               {"current_rms.elbow": 2.0})
    (drift,) = with_residual([], residual_alarms([row]))
    advice = drift.evidence[1]
    assert "`cellguard excite CELL --seconds 20 --out DIR`" in advice, advice
    assert "--only elbow,armature (or --params payload)" in advice, advice
