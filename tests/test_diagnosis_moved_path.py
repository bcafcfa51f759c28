"""A fixture shift sends the arm to another pick point: its joints move through other angles, so their
tracking errors and currents shift a little. That is the new path's, told in the geometry finding, not a
drive fault; a drive that changed with it changes more and is still named (synthetic cycles, fast; the
sizes are the probe's arm, seed 11, fixture shifted 4 mm in x at cycle 22)."""

from __future__ import annotations

import re

import numpy as np
import pytest
from test_diagnosis_rules import _scale

from cellguard.diagnose import diagnose

ELBOW = {"current_rms.elbow": 0.40, "current_peak.elbow": 1.0, "tracking_rms.elbow": 0.015,
         "tracking_max.elbow": 0.045, "friction_torque.elbow": 0.70}
GEOMETRY = {f"{stem}_{axis}_mm": v for stem, v in (("part_seen", 300.0), ("fixture_seen", 320.0), ("grasp_tcp", 300.0),
                                                     ("grasp_offset", 0.0)) for axis, v in (("x", v), ("y", 0.1 * v))}
NEW_PATH = {"tracking_rms.elbow": 1.013, "tracking_max.elbow": 1.013, "current_rms.elbow": 0.997}  # fixture alone
SERVO = {"tracking_rms.elbow": 1.045, "tracking_max.elbow": 1.04, "current_rms.elbow": 1.006}  # with gain x0.8
FRICTION = {"friction_torque.elbow": 1.159, "current_rms.elbow": 1.101, "current_peak.elbow": 1.08,
            "tracking_rms.elbow": 1.029}  # with friction x1.5


def _shifted(elbow: dict[str, float], joint_at: int = 25, seed: int = 0) -> list[dict]:
    """An arm whose fixture moves 4 mm in x from cycle 25 (the grasp pose follows 3 mm, the offset takes
    the rest), its elbow's features scaled by ``elbow`` from ``joint_at`` on."""
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(45):
        f = {k: v + (0.01 if k.endswith("_mm") else 2e-3 * v) * rng.standard_normal()
             for k, v in {**ELBOW, **GEOMETRY}.items()}
        if i >= 25:
            for k, d in (("part_seen_x_mm", 4.0), ("fixture_seen_x_mm", 4.0), ("grasp_tcp_x_mm", 3.0),
                         ("grasp_offset_x_mm", 1.0)):
                f[k] += d
        if i >= joint_at:
            _scale(f, elbow)
        rows.append({"cycle": i, "phase": "acceptance" if i < 15 else "production", "success": True, "features": f})
    return rows


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_joint_change_the_moved_pick_point_brings_is_told_in_the_fixture_shift(seed):
    """The probe's elbow: tracking error +1.3 %, current -0.3 % from the shift on (named servo at 0.95)."""
    d = diagnose(_shifted(NEW_PATH, seed=seed), [], {})
    assert [(f.cause, f.cycle) for f in d.findings] == [("fixture_shift", 25)], [f.to_dict() for f in d.findings]
    words = " ".join(d.findings[0].evidence)
    assert re.search(r"also elbow from cycle 25: current -0\.\d %, tracking error \+1\.\d %: the arm moves to "
                     "another pick point, not a change in its drive", words), words
    assert any(s.endswith(".elbow") for s in d.findings[0].signals)


@pytest.mark.parametrize("change, cause", [(SERVO, "servo"), (FRICTION, "friction")])
def test_a_drive_that_changed_with_the_fixture_shift_is_still_named(change, cause):
    """Servo gain x0.8 (error +4.5 %) or friction x1.5 (friction torque +16 %) on the elbow, at the shift."""
    d = diagnose(_shifted(change), [], {})
    assert sorted((f.cause, f.cycle, f.joints) for f in d.findings) == [
        ("fixture_shift", 25, ()), (cause, 25, ("elbow",))], [f.to_dict() for f in d.findings]
    assert "another pick point" not in " ".join(d.findings[0].evidence)


def test_a_small_joint_change_long_after_the_fixture_shift_is_its_own():
    """The same small change 10 cycles after the shift did not begin with the new path."""
    d = diagnose(_shifted(NEW_PATH, joint_at=35), [], {})
    assert sorted((f.cause, f.joints) for f in d.findings) == [("fixture_shift", ()), ("servo", ("elbow",))], \
        [f.to_dict() for f in d.findings]
