"""Geometry findings the diagnosis probe 41 found wanting: a tool that slipped along its own axis (z), with the
joints' grasp pose where it was; a camera shift that told only what the camera saw."""

from __future__ import annotations

import numpy as np
from test_diagnosis_rules import GEOMETRY

from cellguard.diagnose import diagnose

CENTRE = {**GEOMETRY, "grasp_tcp_z_mm": 50.0, "grasp_offset_z_mm": 0.0, "grasp_q.elbow": 1.2, "grasp_q.wrist_flex": 0.4}


def _slipped_in_z(joints_moved: bool = False, seed: int = 3) -> list[dict]:
    """The tool point 3 mm along z on the flange from cycle 24: the offset +3 mm, the tool point seen -3 mm;
    the joints' grasp pose where it was (or moved, ``joints_moved``)."""
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(34):
        f = {k: v + (0.02 if k.endswith("_mm") else 1e-4) * rng.standard_normal() for k, v in CENTRE.items()}
        if i >= 24:
            f["grasp_offset_z_mm"] += 3.0
            f["grasp_tcp_z_mm"] -= 3.0
            f["grasp_q.elbow"] += 0.06 if joints_moved else 0.0  # 5 scales (1 % of its angle)
        rows.append({"cycle": i, "phase": "acceptance" if i < 20 else "production", "success": True, "features": f})
    return rows


def test_a_tool_that_slipped_along_z_with_the_joints_unchanged_is_a_tool_slip():
    d = diagnose(_slipped_in_z(), [], {})
    assert [(f.cause, f.cycle) for f in d.findings] == [("tool_slip", 24)], [f.to_dict() for f in d.findings]
    words = " ".join(d.findings[0].evidence)
    assert "+3.0 mm in z" in words and "joint grasp pose unchanged" in words and "another point" not in words, words


def test_a_grasp_the_joints_moved_in_z_is_where_the_tool_closed():
    d = diagnose(_slipped_in_z(joints_moved=True), [], {})
    assert [f.cause for f in d.findings] == ["unknown"], [f.to_dict() for f in d.findings]
    assert "the tool closed on it at another point" in " ".join(d.findings[0].evidence)


def test_a_camera_shift_tells_the_cameras_own_move():
    """The camera moved +3 mm in y: it sees part and fixture -3 mm, the arm goes there and closes 3 mm off the part."""
    rng = np.random.default_rng(4)
    rows = []
    for i in range(34):
        f = {k: v + 0.02 * rng.standard_normal() for k, v in GEOMETRY.items()}
        if i >= 24:
            for k, d in (("part_seen_y_mm", -3.0), ("fixture_seen_y_mm", -3.0), ("grasp_tcp_y_mm", -3.0),
                         ("grasp_offset_y_mm", 3.0)):
                f[k] += d
        rows.append({"cycle": i, "phase": "acceptance" if i < 20 else "production", "success": True, "features": f})
    d = diagnose(rows, [], {})
    assert [(f.cause, f.cycle) for f in d.findings] == [("camera_shift", 24)], [f.to_dict() for f in d.findings]
    assert "the camera moved, about +0.0 mm in x, +3.0 mm in y" in " ".join(d.findings[0].evidence)
