"""Profile validation: every disagreement with the model is refused with the field named."""

from __future__ import annotations

import math

import pytest
import yaml

from cellguard.embodiment import load_profile
from cellguard.errors import ProfileError
from cellguard.robot.arm_cell import ASSETS
from cellguard.units import parse_quantity


@pytest.fixture
def raw() -> dict:
    return yaml.safe_load((ASSETS / "arm_profile.yaml").read_text())


def _load(arm, raw, tmp_path):
    path = tmp_path / "profile.yaml"
    path.write_text(yaml.safe_dump(raw))
    return load_profile(arm.model, path)


def test_shipped_profile_loads_in_si(arm):
    p = arm.profile
    assert p.joint_names == ("shoulder_pan", "shoulder_lift", "elbow", "wrist_flex", "wrist_roll", "gripper")
    assert p.joints[5].kind == "slide" and p.joints[5].position == pytest.approx((0.006, 0.029))
    assert p.array("velocity")[2] == 3.0
    assert not p.array("velocity").flags.writeable
    backlash = next(m for m in p.measured if m.parameter == "backlash")
    assert backlash.value == pytest.approx(math.radians(0.05)) and backlash.unit == "deg"
    assert len(p.sha256) == 64


def test_degrees_convert_to_radians(arm, raw, tmp_path):
    raw["joints"]["elbow"]["position"] = ["-90 deg", "90 deg"]
    p = _load(arm, raw, tmp_path)
    assert p.joints[p.index("elbow")].position == pytest.approx((-math.pi / 2, math.pi / 2))


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda r: r["joints"].__setitem__("knee", r["joints"]["elbow"]), "joints.knee: unknown joint"),
        (lambda r: r["joints"]["elbow"].__setitem__("position", ["-3 rad", "2 rad"]), "outside the model's range"),
        (lambda r: r["joints"]["elbow"].__setitem__("velocity", 3.0), "joints.elbow.velocity: missing unit"),
        (lambda r: r["joints"]["elbow"].__setitem__("velocity", "3 m/s"), "joints.elbow.velocity: unit 'm/s' does not fit"),
        (lambda r: r["joints"]["elbow"].pop("jerk"), "joints.elbow.jerk: missing"),
        (lambda r: r["joints"]["elbow"].__setitem__("jerk", "-1 rad/s^3"), "must be positive"),
        (lambda r: r["joints"]["gripper"].__setitem__("position", ["6 deg", "29 deg"]), "joints.gripper.position[0]"),
        (lambda r: r.__setitem__("colour", "red"), "colour: unknown key"),
        (lambda r: r["measured"][0].pop("method"), "measured[0].method: missing"),
        (lambda r: r["measured"][0].__setitem__("value", "0.2"), "measured[0].value: missing unit"),
        (lambda r: r.__setitem__("symmetry", [{"left": "elbow", "right": "hip", "sign": 1}]), "symmetry[0].right"),
        (lambda r: r.__setitem__("symmetry", [{"left": "elbow", "right": "wrist_flex", "sign": 2}]), "symmetry[0].sign"),
    ],
)
def test_bad_profile_names_the_field(arm, raw, tmp_path, edit, message):
    edit(raw)
    with pytest.raises(ProfileError, match=message.replace("[", r"\[").replace("(", r"\(")):
        _load(arm, raw, tmp_path)


def test_malformed_yaml_is_one_error(arm, tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("joints: [unclosed")
    with pytest.raises(ProfileError, match="not valid YAML"):
        load_profile(arm.model, path)


def test_quantity_parser_rejects_non_finite():
    with pytest.raises(ValueError, match="not finite"):
        parse_quantity("nan rad", "x", ("angle",))


# -- measured values: checked against their parameter and joint (the dimension, friction a torque on a
# hinge and a force on a slide; at least zero; a sane size; one entry per joint and parameter); text fields
# hold no control characters, and the version can name a file


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
