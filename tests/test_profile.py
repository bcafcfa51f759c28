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
