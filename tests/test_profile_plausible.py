"""Profile limits no robot has are refused, and `embodiment show` never shows a limit wider than it is.

A velocity of "1e308 rad/s" (or acceleration, jerk) switched the guard off: any step passed and the stopping
distance overflowed; "1e-300 rad/s" was taken too. `embodiment show` rounded velocity, acceleration, jerk and
effort to the nearest (2.9999999 rad/s shown 3)."""

from __future__ import annotations

import math

import pytest
import yaml
from hypothesis import example, given
from hypothesis import strategies as st
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.cli.embodiment import _inward
from cellguard.embodiment.profile import SI_UNITS, parse_profile
from cellguard.errors import ProfileError
from cellguard.robot.arm_cell import ASSETS
from cellguard.robot.registry import make_cell

runner = CliRunner()
MODEL = make_cell("arm-pick-place").model
RAW = yaml.safe_load((ASSETS / "arm_profile.yaml").read_text())
LIMITS = ("velocity", "acceleration", "jerk", "effort", "torque_constant")
# the plausible range of each limit, as written in the check's comment (profile._PLAUSIBLE)
RANGE = {"velocity": (1e-6, 1e3), "acceleration": (1e-6, 1e6), "jerk": (1e-6, 1e9), "effort": (1e-6, 1e7),
         "torque_constant": (1e-6, 1e6)}


def _profile_text(joint: str, key: str, text: str) -> bytes:
    raw = yaml.safe_load(yaml.safe_dump(RAW))
    raw["joints"][joint][key] = text
    return yaml.safe_dump(raw, sort_keys=False).encode()


# wrist_roll (a hinge) and the gripper (a slide) have no measured friction an effort limit must stay above
@given(joint=st.sampled_from(["wrist_roll", "gripper"]), key=st.sampled_from(LIMITS),
       value=st.floats(min_value=0.0, max_value=1e308, exclude_min=True))
@example(joint="wrist_roll", key="velocity", value=1e308)
@example(joint="wrist_roll", key="velocity", value=1e-300)
@example(joint="gripper", key="jerk", value=1e9)
@example(joint="wrist_roll", key="acceleration", value=1e-6)
def test_a_limit_loads_exactly_inside_its_plausible_range_and_is_refused_in_one_line_outside(joint, key, value):
    unit = SI_UNITS["slide" if joint == "gripper" else "hinge"][key]
    low, high = RANGE[key]
    text = _profile_text(joint, key, f"{value!r} {unit}")
    if low <= value <= high:
        profile = parse_profile(MODEL, text)
        assert profile.array(key)[profile.index(joint)] == value
        return
    with pytest.raises(ProfileError) as caught:
        parse_profile(MODEL, text)
    message = str(caught.value)
    assert message.startswith(f"profile: joints.{joint}.{key}: {value!r} {unit} is outside the plausible "
                              f"{low:g}..{high:g} {unit}") and "\n" not in message


def test_the_shipped_profiles_are_plausible():
    """The bounds leave every cell's own limits inside them by an order of magnitude at least."""
    for cell in ("arm-pick-place", "quadruped-turns"):
        profile = make_cell(cell).profile
        for key in LIMITS:
            low, high = RANGE[key]
            values = profile.array(key)
            assert (values >= 10 * low).all() and (values <= high / 10).all(), (cell, key)


def _write(tmp_path, joint: str, key: str, text: str):
    path = tmp_path / "profile.yaml"
    path.write_bytes(_profile_text(joint, key, text))
    return path


def test_show_and_a_scenarios_calibration_refuse_an_absurd_limit_exit_2(tmp_path):
    path = _write(tmp_path, "shoulder_pan", "velocity", "1e308 rad/s")
    says = "joints.shoulder_pan.velocity: 1e308 rad/s is outside the plausible 1e-06..1000 rad/s"
    shown = runner.invoke(app, ["embodiment", "show", "arm-pick-place", "--profile", str(path)])
    assert shown.exit_code == 2 and says in shown.stderr and shown.stderr.count("\n") == 1, shown.output
    scenario = tmp_path / "scenario.yaml"
    scenario.write_text(f"cell: arm-pick-place\nseed: 1\npolicy: scripted\nacceptance_cycles: 1\n"
                        f"production_cycles: 0\ncalibration: {path}\n")
    run = runner.invoke(app, ["run", str(scenario), "--out", str(tmp_path / "out")])
    assert run.exit_code == 2 and f"calibration: {path}: {says}" in run.stderr, run.output
    assert run.stderr.count("\n") == 1 and not (tmp_path / "out").exists()


def _shown(tmp_path, edits: dict[tuple[str, str], str]) -> dict[str, list[str]]:
    raw = yaml.safe_load(yaml.safe_dump(RAW))
    for (joint, key), text in edits.items():
        raw["joints"][joint][key] = text
    path = tmp_path / "profile.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    result = runner.invoke(app, ["embodiment", "show", "arm-pick-place", "--profile", str(path)],
                           env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    return {line.split()[0]: line.split()[1:] for line in result.output.splitlines() if ".." in line}


def test_show_rounds_velocity_acceleration_jerk_and_effort_inward(tmp_path):
    """2.9999999 rad/s was shown 3, 1499.99999 rad/s^3 1500, 7.999999 N*m 8, 170 deg/s (2.9670597 rad/s) 2.96706."""
    rows = _shown(tmp_path, {("shoulder_pan", "velocity"): "2.9999999 rad/s", ("elbow", "velocity"): "170 deg/s",
                             ("wrist_flex", "jerk"): "1499.99999 rad/s^3", ("wrist_flex", "effort"): "7.999999 N*m",
                             ("wrist_roll", "acceleration"): "29.99999 rad/s^2", ("gripper", "effort"): "19.99999 N"})
    assert rows["shoulder_pan"][1] == "2.999" and rows["elbow"][1] == "2.967"
    assert rows["wrist_flex"][3:5] == ["1499", "7.999"] and rows["wrist_roll"][2] == "29.99"
    assert rows["gripper"][4] == "19.99"
    assert rows["shoulder_lift"][1:5] == ["3", "15", "1000", "30"]  # a round value stays as it is


@given(st.floats(min_value=1e-300, max_value=1e300), st.booleans())
def test_a_shown_limit_is_never_wider_and_within_a_thousandth(magnitude, negative):
    value = -magnitude if negative else magnitude
    ceiling, floor = float(_inward(value, up=True)), float(_inward(value, up=False))  # a lower, an upper limit
    assert floor <= value <= ceiling
    assert math.isclose(floor, value, rel_tol=1e-3) and math.isclose(ceiling, value, rel_tol=1e-3)
