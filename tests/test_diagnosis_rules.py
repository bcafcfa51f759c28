"""Cause rules on synthetic cycles (fast): what a position-servo arm's friction looks like, a
latency that explains a mirrored asymmetry, intermittent and geometry findings told once, a weak
leg's own joints compensating, the onset of a fixture shift."""

from __future__ import annotations

import re

import numpy as np
from test_diagnose_legs import _legged

from cellguard.diagnose import Baseline, as_cycles, diagnose, mirrored_asymmetry
from cellguard.diagnose.cause import name_causes
from cellguard.diagnose.drift import DriftAlarm
from cellguard.embodiment.profile import SymmetryPair

SO101 = {"current_rms.elbow_flex": 0.30, "current_peak.elbow_flex": 0.80, "tracking_rms.elbow_flex": 0.020,
         "tracking_max.elbow_flex": 0.060, "friction_torque.elbow_flex": 0.25,
         "current_rms.shoulder_lift": 0.50, "current_peak.shoulder_lift": 1.2, "tracking_rms.shoulder_lift": 0.015,
         "tracking_max.shoulder_lift": 0.045, "friction_torque.shoulder_lift": 0.30}


def _arm(change, seed: int = 0, centre: dict = SO101, n: int = 40, at: int = 25) -> list[dict]:
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n):
        f = {k: v + (0.01 if k.endswith("_mm") else 2e-3 * v) * rng.standard_normal() for k, v in centre.items()}
        if i >= at:
            change(f)
        rows.append({"cycle": i, "phase": "acceptance" if i < 15 else "production", "success": True, "features": f})
    return rows


def _scale(f: dict, factors: dict[str, float]) -> None:
    for k, v in factors.items():
        f[k] *= v


def test_friction_on_a_position_servo_raises_tracking_as_much_as_current_and_is_named_friction():
    """SO-101 elbow_flex friction x2: current +12 %, tracking error +12 % (the servo holds the extra
    torque through a larger error), friction torque +14 %: friction, not a servo gain loss."""
    d = diagnose(_arm(lambda f: _scale(f, {"current_rms.elbow_flex": 1.119, "current_peak.elbow_flex": 1.066,
                                           "tracking_rms.elbow_flex": 1.121, "tracking_max.elbow_flex": 1.07,
                                           "friction_torque.elbow_flex": 1.144})), [], {})
    assert [(f.cause, f.joints) for f in d.findings] == [("friction", ("elbow_flex",))]
    words = " ".join(d.findings[0].evidence)
    assert re.search(r"elbow_flex: friction torque \+1[45]\.\d %, current \+1[12]\.\d %, tracking error \+1[12]\.\d %",
                     words), words


def test_a_servo_gain_loss_leaves_the_friction_torque_and_stays_servo():
    d = diagnose(_arm(lambda f: _scale(f, {"current_peak.shoulder_lift": 0.96, "tracking_rms.shoulder_lift": 1.25,
                                           "tracking_max.shoulder_lift": 1.21,
                                           "friction_torque.shoulder_lift": 0.995})), [], {})
    assert [(f.cause, f.joints) for f in d.findings] == [("servo", ("shoulder_lift",))]


LEGS = ("fl", "fr", "rl", "rr")
PAIRS = tuple(SymmetryPair(f"{end}l_{j}", f"{end}r_{j}", 1.0) for end in "fr" for j in ("hip", "knee"))


def _turning(change, seed: int = 0, n: int = 50, at: int = 30) -> list[dict]:
    """A four-legged robot turning left and right in turn; ``change(features, turn)`` from cycle ``at``."""
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n):
        turn = "left" if i % 2 == 0 else "right"
        f = {"latency_mean_ms": 10.0 + 0.1 * rng.standard_normal()}
        for leg in LEGS:
            inner = (leg[1] == "l") == (turn == "left")  # the leg on the side the robot turns to
            f[f"contact_duty.{leg}"] = (0.55 if inner else 0.45) * (1 + 2e-3 * rng.standard_normal())
            for j, (trk, cur) in {"hip": (0.010, 2.0), "knee": (0.012, 3.0)}.items():
                k = 1.0 if inner else 1.2
                f[f"tracking_rms.{leg}_{j}"] = trk * k * (1 + 2e-3 * rng.standard_normal())
                f[f"current_rms.{leg}_{j}"] = cur * k * (1 + 2e-3 * rng.standard_normal())
        if i >= at:
            change(f, turn)
        rows.append({"cycle": i, "phase": "acceptance" if i < 20 else "production", "direction": turn, "features": f})
    return rows


def _late_policy(f: dict, turn: str) -> None:
    """200 ms more latency: every foot's timing shifts, and the stale plan loads the right legs less in left turns."""
    f["latency_mean_ms"] += 200.0
    for leg in LEGS:
        f[f"contact_duty.{leg}"] *= 0.8
    if turn == "left":
        _scale(f, {f"{k}.{leg}_{j}": 0.8 for k in ("tracking_rms", "current_rms") for leg in ("fr", "rr")
                   for j in ("hip", "knee")})


def test_an_asymmetry_that_began_with_the_latency_is_told_in_the_latency_finding():
    d = diagnose(_turning(_late_policy), [], {}, symmetry=PAIRS)
    assert d.asymmetry is not None and d.asymmetry.side
    assert [(f.cause, f.cycle) for f in d.findings] == [("policy_latency", 30)], [f.to_dict() for f in d.findings]
    words = " ".join(d.findings[0].evidence)
    assert f"mirrored motions differ on the {d.asymmetry.side} side from cycle 30" in words
    assert "also the gait of leg fl, fr, rl, rr from cycle 30" in words


def test_an_asymmetry_that_began_long_after_a_latency_is_a_finding_of_its_own():
    """A latency from cycle 25 swallowed an asymmetry that began at 80: 'began with it' has a lower bound too."""
    from cellguard.diagnose.asymmetry import Asymmetry, MirrorDifference
    from cellguard.diagnose.cause import Finding
    from cellguard.diagnose.diagnosis import _with_asymmetry

    d = MirrorDifference("tracking_rms.lf_knee", "tracking_rms.lf_knee", "tracking_rms.rf_knee", 0.02, 0.01, 0.66, 9.0,
                         "tracking_rms.rf_knee", ("", ""))
    asym = Asymmetry("left", ("lf_knee",), (d,), ("mirrored motions differ", "lf_knee tracks 66% worse"))
    late = Finding("policy_latency", 25, 0.9, ("latency +40 ms from cycle 25",), ("latency_mean_ms",))
    assert [(f.cause, f.cycle) for f in _with_asymmetry([late], asym, began=80)] == [("policy_latency", 25),
                                                                                     ("servo", 80)]
    assert [f.cause for f in _with_asymmetry([late], asym, began=26)] == ["policy_latency"]


def test_a_gait_asymmetry_told_in_a_latency_finding_names_what_differs():
    """A quadruped's sides differ in their gait, on no joint: the latency finding said "from cycle 12 ():"."""
    from cellguard.diagnose.asymmetry import Asymmetry, MirrorDifference
    from cellguard.diagnose.cause import Finding
    from cellguard.diagnose.diagnosis import _with_asymmetry

    d = MirrorDifference("step_period_s.rl", "step_period_s.rl during left turns", "step_period_s.rr during right turns",
                         1.45, 0.73, 0.66, 130.0, "step_period_s.rr", ("left", "right"))
    asym = Asymmetry("right", (), (d,), ("the right side differs from its mirror",))
    late = Finding("policy_latency", 12, 0.95, ("latency +200 ms from cycle 12",), ("latency_mean_ms",))
    (told,) = _with_asymmetry([late], asym, began=12)
    assert told.evidence[-1].startswith("mirrored motions differ on the right side from cycle 12 (step_period_s): ")


def test_an_asymmetry_is_dated_when_it_began_not_at_the_first_production_cycle():
    from cellguard.diagnose.asymmetry import asymmetry_onset

    def right_legs_weaker(f: dict, turn: str) -> None:
        if turn == "left":
            _scale(f, {f"tracking_rms.{leg}_{j}": 1.15 for leg in ("fr", "rr") for j in ("hip", "knee")})

    cycles = as_cycles(_turning(right_legs_weaker, at=34))
    watched = [c for c in cycles if c.phase == "production"]
    asym = mirrored_asymmetry(watched, PAIRS)
    assert asym.side == "right"
    assert asymmetry_onset(cycles, asym, PAIRS, watched[0].index) == 34
    always = as_cycles(_turning(right_legs_weaker, at=0))  # there since acceptance: from the first watched cycle
    assert asymmetry_onset(always, mirrored_asymmetry(always[20:], PAIRS), PAIRS, 20) == 20


def test_an_alarm_raised_twice_is_told_once():
    cycles = as_cycles(_turning(lambda f, turn: _scale(f, {"contact_duty.fl": 0.8})))
    base = Baseline.from_cycles([c for c in cycles if c.phase == "acceptance"])
    watched = [c for c in cycles if c.phase == "production"]
    z = base.residuals(watched)
    alarms = [DriftAlarm("contact_duty.fl", 32, 9.0, 30, -1), DriftAlarm("contact_duty.fl", 36, 9.0, 34, -1)]
    (f,) = name_causes(base, watched, z, alarms)
    assert f.cause == "foot_contact" and sum("contact_duty.fl" in e for e in f.evidence) == 1, f.evidence


GEOMETRY = {f"{stem}_{axis}_mm": v for stem, v in (("part_seen", 300.0), ("fixture_seen", 320.0), ("grasp_tcp", 300.0),
                                                     ("grasp_offset", 0.0)) for axis, v in (("x", v), ("y", 0.1 * v))}


def _slips(seed: int = 3) -> list[dict]:
    """A tool that slips on some cycles from 24 on: the part-to-tool offset and the place error off on those."""
    hit = {24, 27, 31, 32, 36, 41}
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(50):
        f = {k: v + 0.02 * rng.standard_normal() for k, v in {**GEOMETRY, "place_error_mm": 0.5}.items()}
        if i in hit:
            f["grasp_offset_x_mm"] += 3.0
            f["place_error_mm"] += 3.0
        rows.append({"cycle": i, "phase": "acceptance" if i < 20 else "production", "success": True, "features": f})
    return rows


def test_an_intermittent_fault_is_one_finding_whatever_it_shows_in():
    d = diagnose(_slips(), [], {})
    assert [(f.cause, f.cycle) for f in d.findings] == [("tool_slip", 24)], [f.to_dict() for f in d.findings]
    assert "also place_error_mm off on the same cycles" in d.findings[0].evidence


def _grasp_lower(f: dict) -> None:
    """The tool closes 0.2 mm higher on a part that sits where it did (the offset takes it back)."""
    f["grasp_tcp_z_mm"] += 0.2
    f["grasp_offset_z_mm"] -= 0.2


WITH_Z = {**SO101, **GEOMETRY, "grasp_tcp_z_mm": 50.0, "grasp_offset_z_mm": 0.0}


def test_a_grasp_that_moved_in_z_only_is_told_in_z():
    d = diagnose(_arm(_grasp_lower, centre=WITH_Z), [], {})
    assert [f.cause for f in d.findings] == ["unknown"], [f.to_dict() for f in d.findings]
    words = " ".join(d.findings[0].evidence)
    assert "grasp_tcp_z_mm +0.2" in words and "grasp_offset_z_mm -0.2" in words and "in x" not in words, words


def test_a_grasp_moved_with_a_weaker_servo_is_that_servo_s_consequence():
    def weaker_and_grasp(f: dict) -> None:
        _scale(f, {"tracking_rms.shoulder_lift": 1.25, "tracking_max.shoulder_lift": 1.21})
        _grasp_lower(f)

    d = diagnose(_arm(weaker_and_grasp, centre=WITH_Z), [], {})
    found = [(f.cause, f.joints) for f in d.findings]
    assert found == [("servo", ("shoulder_lift",))], [f.to_dict() for f in d.findings]
    assert "the tool closed at another point of its path" in " ".join(d.findings[0].evidence)


def test_the_weak_leg_s_own_joints_compensating_are_folded_into_its_servo_finding():
    def weak_rear_left_hip(f: dict) -> None:
        _scale(f, {"tracking_rms.rl_hip": 1.1, "tracking_max.rl_hip": 1.1})
        _scale(f, {f"{k}.{j}": 1.08 for k in ("current_rms", "current_peak") for j in ("rl_knee", "fl_hip", "rr_knee")})

    d = diagnose(_legged(weak_rear_left_hip), [], {}, symmetry=PAIRS)
    assert [(f.cause, f.joints, f.legs) for f in d.findings] == [("servo", ("rl_hip",), ("rl",))], \
        [f.to_dict() for f in d.findings]
    assert "rl_knee on the weak leg itself among them" in " ".join(d.findings[0].evidence)


def test_a_fixture_shift_is_dated_at_its_step_not_at_an_early_change_point_of_a_noisy_feature():
    """The part's place varies from part to part: two cycles that happen to sit high before the shift
    start its CUSUM early. The step itself is fitted over every cycle on both sides."""
    rng = np.random.default_rng(7)
    rows = []
    for i in range(50):
        f = {k: v + 0.02 * rng.standard_normal() for k, v in {**GEOMETRY, "place_error_mm": 0.5}.items()}
        if i in (30, 31):  # noise before the step, 2 scales high
            f["part_seen_y_mm"] += 0.1
            f["grasp_tcp_y_mm"] += 0.1
        if i >= 32:
            for k in ("part_seen_y_mm", "fixture_seen_y_mm", "grasp_tcp_y_mm"):
                f[k] += 1.0
        rows.append({"cycle": i, "phase": "acceptance" if i < 20 else "production", "success": True, "features": f})
    d = diagnose(rows, [], {})
    assert [(f.cause, f.cycle) for f in d.findings] == [("fixture_shift", 32)], [f.to_dict() for f in d.findings]
    assert {a.onset for a in d.drift.alarms if a.signal == "part_seen_y_mm"} == {30}  # what the median read
    # and the report's "What changed, in the order it began" dates the feature by its step too (it read 30)
    assert {c.signal: c.onset for c in d.changes}["part_seen_y_mm"] == 32
    assert min(c.onset for c in d.changes) == 32


def test_an_inertia_like_residual_on_a_weaker_servo_s_joint_is_that_servo_s_evidence():
    from cellguard.diagnose.cause import Finding
    from cellguard.diagnose.residual import with_residual

    alarm = {"cycle": 15, "joint": "wrist_flex", "parameter": "inertia/payload", "signature": "inertia",
             "message": "inertia/payload-like residual"}
    servo = Finding("servo", 14, 0.88, ("tracking up",), ("tracking_rms.wrist_flex",), ("wrist_flex",))
    merged = with_residual([servo], [alarm])
    assert [f.cause for f in merged] == ["servo"], merged
    assert merged[0].evidence[-1].startswith("residual monitor, cycle 15: inertia/payload-like residual")


def test_a_joint_whose_error_grew_with_no_more_current_is_not_another_joint_s_consequence():
    """Friction x2 on one joint and a 20 % weaker servo on another, from the same cycle: the weaker joint's
    change is under a fifth of the other's, but a coupled joint's change reaches it as a load (current)."""
    def two(f: dict) -> None:
        _scale(f, {"current_rms.shoulder_lift": 1.237, "current_peak.shoulder_lift": 1.117,
                   "tracking_rms.shoulder_lift": 1.057, "tracking_max.shoulder_lift": 1.03,
                   "friction_torque.shoulder_lift": 1.287,
                   "tracking_rms.elbow_flex": 1.032, "tracking_max.elbow_flex": 1.031})

    d = diagnose(_arm(two), [], {})
    found = sorted((f.cause, f.joints) for f in d.findings)
    assert found == [("friction", ("shoulder_lift",)), ("servo", ("elbow_flex",))]
