"""The URDF in a record states each moving joint's limits from the profile: it said effort="0" velocity="0" on every
one, which a URDF reader (MoveIt, a planner) takes as a joint that cannot move or push."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import pytest
from run_copies import recorded  # noqa: F401 (fixture)

from cellguard.record.reader import open_record
from cellguard.record.writer import DESCRIPTION_FILE
from cellguard.robot.registry import make_cell


def test_every_moving_joint_states_the_profiles_effort_and_velocity(recorded):
    with open_record(recorded) as rec:
        urdf = ET.fromstring(rec.attachment(DESCRIPTION_FILE))
    profile = make_cell("arm-pick-place", seed=5).profile
    moving = {j.get("name"): j.find("limit") for j in urdf.iter("joint") if j.get("type") in ("revolute", "prismatic")}
    assert sorted(moving) == sorted(profile.joint_names)
    for joint in profile.joints:
        limit = moving[joint.name]
        assert float(limit.get("effort")) == pytest.approx(joint.effort, rel=1e-5) and joint.effort > 0
        assert float(limit.get("velocity")) == pytest.approx(joint.velocity, rel=1e-5) and joint.velocity > 0
