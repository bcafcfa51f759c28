"""The record's URDF states the position limits the guard enforced (the profile's), not the MJCF model's wider
joint ranges: Foxglove showed shoulder_pan's -2.6..2.6 where the guard held it to -2.5..2.5."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import mujoco
import pytest

from cellguard.record.urdf import describe
from cellguard.robot.registry import make_cell


def test_every_moving_joint_states_the_profiles_position_limits():
    cell = make_cell("arm-pick-place", seed=5)
    profile, model = cell.profile, cell.model
    urdf = ET.fromstring(describe(model, profile)[0])
    limits = {j.get("name"): j.find("limit") for j in urdf.iter("joint") if j.get("type") in ("revolute", "prismatic")}
    assert sorted(limits) == sorted(profile.joint_names)
    for joint in profile.joints:
        stated = (float(limits[joint.name].get("lower")), float(limits[joint.name].get("upper")))
        assert stated == pytest.approx(joint.position, rel=1e-5)
    pan = model.jnt_range[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "shoulder_pan")]
    assert pan[1] > profile.joints[profile.index("shoulder_pan")].position[1]  # the model's range is wider
