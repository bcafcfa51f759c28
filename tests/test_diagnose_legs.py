"""Issue 16 on the legged robot and on loaded joints: friction seen in the friction torque (the
current's RMS does not show it), and a weak leg's servo named on that leg with the other legs'
compensation told as its evidence (fast: synthetic ticks and cycles)."""

from __future__ import annotations

import numpy as np
import pytest

from cellguard.diagnose import diagnose
from cellguard.diagnose.cycle_buffer import CycleBuffer
from cellguard.diagnose.features import cycle_features
from cellguard.embodiment.profile import SymmetryPair
from cellguard.robot.arm_cell import ArmPickPlace
from cellguard.robot.state import State


def _loaded_cycle(profile, dry: float, amplitude: float = 0.5) -> dict[str, float]:
    """One 2 s cycle that returns to its start: a gravity-like load of q, inertia, and dry friction ``dry``."""
    t = np.arange(2001) * 1e-3
    q = amplitude * np.sin(np.pi * t)
    qd = amplitude * np.pi * np.cos(np.pi * t)
    qdd = -amplitude * np.pi ** 2 * np.sin(np.pi * t)
    effort = 8.0 * np.sin(q + 0.3) + 0.2 * qdd + dry * np.sign(qd)
    buf = CycleBuffer(profile.dof, len(t))
    ones = np.ones(profile.dof)
    for k in range(len(t)):
        buf.add(q[k] * ones, q[k] * ones, State(int(t[k] * 1e9), q[k] * ones, qd[k] * ones, effort[k] * ones,
                                                effort[k] * ones))
    return cycle_features(profile, buf, {}, [], [])


def test_friction_torque_is_the_drive_work_over_the_travel_where_the_current_rms_barely_moves():
    profile = ArmPickPlace().profile
    joint = profile.joint_names[1]
    before, after = _loaded_cycle(profile, 0.2), _loaded_cycle(profile, 0.3)
    assert before[f"friction_torque.{joint}"] == pytest.approx(0.2, abs=0.01)
    assert after[f"friction_torque.{joint}"] - before[f"friction_torque.{joint}"] == pytest.approx(0.1, abs=0.005)
    assert abs(after[f"current_rms.{joint}"] / before[f"current_rms.{joint}"] - 1.0) < 0.01  # +50 % friction, <1 % RMS


def test_a_joint_that_hardly_moved_has_no_friction_torque():
    profile = ArmPickPlace().profile
    still = _loaded_cycle(profile, 0.2, amplitude=0.01)
    assert not any(k.startswith("friction_torque.") for k in still)


LEGS = ("fl", "fr", "rl", "rr")
PAIRS = tuple(SymmetryPair(f"{end}l_{j}", f"{end}r_{j}", 1.0) for end in "fr" for j in ("hip", "knee"))
CENTRE = {**{f"{k}.{leg}_{j}": v for leg in LEGS for j in ("hip", "knee")
             for k, v in (("tracking_rms", 0.01), ("tracking_max", 0.03), ("current_rms", 2.0),
                          ("current_peak", 5.0), ("friction_torque", 0.6))},
          **{f"contact_duty.{leg}": 0.5 for leg in LEGS}}


def _legged(change, seed: int = 0) -> list[dict]:
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(50):
        f = {k: v * (1 + 2e-4 * rng.standard_normal()) for k, v in CENTRE.items()}
        if i >= 30:
            change(f)
        rows.append({"cycle": i, "phase": "acceptance" if i < 20 else "production", "features": f})
    return rows


def _scale(f: dict, factors: dict[str, float]) -> None:
    for k, v in factors.items():
        f[k] *= v


def test_friction_on_a_loaded_knee_is_named_from_its_friction_torque():
    d = diagnose(_legged(lambda f: _scale(f, {"friction_torque.fl_knee": 1.08, "tracking_max.fl_knee": 1.004})),
                 [], {}, symmetry=PAIRS)
    assert [(f.cause, f.joints, f.legs) for f in d.findings] == [("friction", ("fl_knee",), ("fl",))]
    assert "fl_knee: friction torque +8.0 %" in " ".join(d.findings[0].evidence)


def _weak_rear_left(f: dict) -> None:
    _scale(f, {f"{k}.rl_{j}": 1.1 for k in ("tracking_rms", "tracking_max") for j in ("hip", "knee")})
    _scale(f, {f"{k}.{leg}_{j}": 1.08 for k in ("current_rms", "current_peak") for leg in ("fl", "rr")
               for j in ("hip", "knee")})
    _scale(f, {"contact_duty.fr": 0.95})


def test_a_weak_leg_is_named_servo_on_that_leg_and_the_others_compensation_is_its_evidence():
    d = diagnose(_legged(_weak_rear_left), [], {}, symmetry=PAIRS)
    assert [(f.cause, f.legs) for f in d.findings] == [("servo", ("rl",))]
    words = " ".join(d.findings[0].evidence)
    assert "leg fl, rr take its share of the body" in words and "leg fr steps differently with it" in words


def test_friction_on_two_legs_without_a_weak_leg_stays_friction():
    d = diagnose(_legged(lambda f: _scale(f, {f"current_rms.{leg}_knee": 1.08 for leg in ("fl", "rr")})),
                 [], {}, symmetry=PAIRS)
    assert {f.cause for f in d.findings} == {"friction"}
