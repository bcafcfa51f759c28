"""A profile's measured values are checked against their parameter and joint: the dimension (friction a torque
on a hinge, a force on a slide), at least zero, a sane size, one entry per joint and parameter; its text
fields hold no control characters, and its version can name a file."""

from __future__ import annotations

import math

import pytest
import yaml

from cellguard.embodiment import load_profile
from cellguard.errors import ProfileError
from cellguard.robot.arm_cell import ASSETS


@pytest.fixture
def raw() -> dict:
    return yaml.safe_load((ASSETS / "arm_profile.yaml").read_text())


def _load(arm, raw, tmp_path):
    path = tmp_path / "profile.yaml"
    path.write_text(yaml.safe_dump(raw))
    return load_profile(arm.model, path)


def _measure(joint: str, parameter: str, value: str):
    return lambda r: r["measured"].append({"joint": joint, "parameter": parameter, "value": value,
                                           "measured": "2026-10-14", "method": "typed in"})


@pytest.mark.parametrize(("edit", "message"), [
    (_measure("wrist_roll", "friction", "5 kg"), "measured[6].value: unit 'kg' does not fit; allowed: N*m"),
    (_measure("wrist_roll", "friction", "5 s"), "measured[6].value: unit 's' does not fit; allowed: N*m"),
    (_measure("gripper", "friction", "5 N*m"), "measured[6].value: unit 'N*m' does not fit; allowed: N"),
    (_measure("wrist_roll", "armature", "1 kg"), "unit 'kg' does not fit; allowed: kg*m^2"),
    (_measure("wrist_roll", "friction", "-50 N*m"), "friction of wrist_roll must be at least zero, got -50 N*m"),
    (_measure("wrist_roll", "armature", "-1 kg*m^2"), "armature of wrist_roll must be at least zero"),
    (_measure("wrist_roll", "damping", "-0.1 N*m*s/rad"), "damping of wrist_roll must be at least zero"),
    (_measure("wrist_roll", "friction", "1e300 N*m"), "is above the joint's effort 5 N*m"),
    (_measure("wrist_roll", "armature", "1e9 kg*m^2"), "armature of wrist_roll 1e9 kg*m^2 is above the most"),
    (_measure("elbow", "friction", "5 N*m"), "measured[6]: friction of elbow is already measured[2]"),
    (lambda r: r.__setitem__("model", [1, 2]), "model: expected text, got list"),
    (lambda r: r.__setitem__("version", "x/../../escaped"), "version: 'x/../../escaped' cannot name a file"),
    (lambda r: r.__setitem__("version", "a\0b"), r"version: 'a\x00b' holds control characters"),
    (lambda r: r["measured"][0].__setitem__("method", "\x1b[2Jsweep"), r"measured[0].method: '\x1b[2Jsweep' holds"),
])
def test_a_measured_value_or_text_that_cannot_be_is_refused(arm, raw, tmp_path, edit, message):
    edit(raw)
    with pytest.raises(ProfileError) as info:
        _load(arm, raw, tmp_path)
    assert message in str(info.value) and str(tmp_path / "profile.yaml") in str(info.value)


def test_each_parameter_takes_its_own_dimension_per_joint_kind(arm, raw, tmp_path):
    raw["measured"] = [
        {"joint": "gripper", "parameter": "friction", "value": "5 N", "measured": "2026-10-14", "method": "x"},
        {"joint": "elbow", "parameter": "armature", "value": "0.05 kg*m^2", "measured": "2026-10-14", "method": "x"},
        {"joint": "gripper", "parameter": "armature", "value": "0.1 kg", "measured": "2026-10-14", "method": "x"},
        {"joint": "elbow", "parameter": "backlash", "value": "0.05 deg", "measured": "2026-10-14", "method": "x"},
        {"joint": "elbow", "parameter": "friction", "value": "0 N*m", "measured": "2026-10-14", "method": "x"},
    ]
    p = _load(arm, raw, tmp_path)
    assert [m.value for m in p.measured] == pytest.approx([5.0, 0.05, 0.1, math.radians(0.05), 0.0])
    assert [m.as_written for m in p.measured] == ["5 N", "0.05 kg*m^2", "0.1 kg", "0.05 deg", "0 N*m"]
