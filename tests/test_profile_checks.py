"""Profile fields that passed unchecked: parameter names, dates, symmetry pairs; YAML dates read as text
everywhere (an impossible one crashed every reader); a unit glued to its number is named as such."""

from __future__ import annotations

import datetime as dt

import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st
from typer.testing import CliRunner

from cellguard.calibrate.identify import parse_only
from cellguard.cli import app
from cellguard.embodiment import load_profile
from cellguard.errors import ConfigError, ProfileError
from cellguard.robot.arm_cell import ASSETS
from cellguard.robot.registry import make_cell
from cellguard.scenario import load_scenario
from cellguard.units import parse_quantity
from cellguard.yaml_file import parse_yaml

runner = CliRunner()
TEXT = (ASSETS / "arm_profile.yaml").read_text()
FIRST = 'measured: "2026-10-14", method: "constant-velocity sweep, both directions"'


def _load(arm, tmp_path, text: str):
    path = tmp_path / "profile.yaml"
    path.write_text(text)
    return load_profile(arm.model, path), path


@given(st.integers(0, 9999), st.integers(0, 99), st.integers(0, 99))
def test_an_unquoted_date_is_the_text_written_whatever_its_day(year, month, day):
    written = f"{year:04d}-{month:02d}-{day:02d}"
    assert parse_yaml(f"a: {written}\nb: !!timestamp {written}\n", "x") == {"a": written, "b": written}


def test_an_impossible_date_in_a_scenario_is_text_not_a_crash(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text("cell: arm-pick-place\nsite: 2026-02-30\n")
    assert load_scenario(path).site == "2026-02-30"


def test_a_tagged_value_that_cannot_be_read_is_one_error():
    with pytest.raises(ConfigError, match=r"^x: line 1: !!int 'abc' is not a whole number"):
        parse_yaml("a: !!int abc\n", "x")


def test_an_unquoted_date_loads_as_text(arm, tmp_path):
    profile, _ = _load(arm, tmp_path, TEXT.replace('measured: "2026-10-14"', "measured: 2026-10-14"))
    assert {m.measured for m in profile.measured} == {"2026-10-14"}


@pytest.mark.parametrize("date, says", [
    ("2026-02-30", "'2026-02-30' is not a date; write YYYY-MM-DD"),  # unquoted: a ValueError out of PyYAML
    ('"2026-13-45"', "'2026-13-45' is not a date"),
    ('"yesterday"', "'yesterday' is not a date"),
    ('"20261014"', "'20261014' is not a date"),
])
def test_a_measured_date_that_is_no_day_is_refused_naming_the_field(arm, tmp_path, date, says):
    with pytest.raises(ProfileError) as info:
        _load(arm, tmp_path, TEXT.replace(FIRST, f'measured: {date}, method: "x"'))
    assert f"profile.yaml: measured[0].measured: {says}" in str(info.value)


def test_tomorrow_in_utc_is_allowed_a_site_east_of_it_is_there_already(arm, tmp_path):
    tomorrow = (dt.datetime.now(dt.timezone.utc).date() + dt.timedelta(days=1)).isoformat()
    profile, _ = _load(arm, tmp_path, TEXT.replace(FIRST, f'measured: "{tomorrow}", method: "x"'))
    assert profile.measured[0].measured == tomorrow


def test_a_calibration_date_is_checked_too(arm, tmp_path):
    calibration = ('calibration: {version: v2, mjcf: arm.v2.xml, date: "2026-11-31", records: [r1], '
                   'previous: "2026-11-01"}\n')
    with pytest.raises(ProfileError, match=r"calibration.date: '2026-11-31' is not a date"):
        _load(arm, tmp_path, TEXT + calibration)


def test_an_unknown_parameter_is_refused_listing_the_known(arm, tmp_path):
    with pytest.raises(ProfileError) as info:
        _load(arm, tmp_path, TEXT.replace('parameter: friction, value: "0.2 N*m"',
                                          'parameter: Friction, value: "-5 N*m"', 1))
    assert ("measured[0].parameter: 'Friction' is not a parameter cellguard knows; known: friction, damping, "
            "armature, actuator_time_constant, backlash") in str(info.value)


@pytest.mark.parametrize("pairs, says", [
    ("[{left: elbow, right: elbow, sign: -1}]", "symmetry[0]: elbow cannot mirror itself"),
    ("[{left: elbow, right: gripper, sign: 1}]", "symmetry[0]: elbow is a hinge and gripper a slide"),
    ("[{left: elbow, right: wrist_flex, sign: 1}, {left: wrist_flex, right: elbow, sign: -1}]",
     "symmetry[1].left: wrist_flex is already paired in symmetry[0]; a joint mirrors one joint"),
    # a joint in two pairs: the mirror map was no permutation, and nothing said so
    ("[{left: elbow, right: wrist_flex, sign: 1}, {left: elbow, right: wrist_roll, sign: 1}]",
     "symmetry[1].left: elbow is already paired in symmetry[0]; a joint mirrors one joint"),
    ("[{left: elbow, right: wrist_flex, sign: 1}, {left: wrist_roll, right: wrist_flex, sign: 1}]",
     "symmetry[1].right: wrist_flex is already paired in symmetry[0]; a joint mirrors one joint"),
])
def test_a_symmetry_pair_that_mirrors_nothing_is_refused(arm, tmp_path, pairs, says):
    with pytest.raises(ProfileError) as info:
        _load(arm, tmp_path, TEXT.replace("symmetry: []", f"symmetry: {pairs}"))
    assert says in str(info.value)


@pytest.mark.parametrize("text, says", [
    ("0.2N*m", "no space between the number and the unit in '0.2N*m'; write '0.2 N*m'"),
    ("-1.5e-3N*m", "write '-1.5e-3 N*m'"),
    ("0.2", "missing unit in '0.2'; write e.g. '0.2 N*m'"),
])
def test_a_unit_glued_to_its_number_is_suggested_with_a_space(text, says):
    with pytest.raises(ConfigError) as info:
        parse_quantity(text, "f", ("torque",))
    assert says in str(info.value)


def test_only_given_twice_is_fitted_once():
    cell = make_cell("arm-pick-place")
    assert parse_only(["elbow,friction", " elbow , friction", "elbow,armature"], cell) == [
        ("elbow", "friction"), ("elbow", "armature")]


def test_show_reads_a_profile_file_and_refuses_another_robots(tmp_path):
    path = tmp_path / "arm_profile.yaml"
    raw = yaml.safe_load(TEXT)
    raw["calibration"] = {"version": "2026-11-02-cal-0000abcd", "mjcf": "a.xml", "date": "2026-11-02",
                          "records": ["r1"], "previous": "2026-11-01"}
    path.write_text(yaml.safe_dump(raw))
    result = runner.invoke(app, ["embodiment", "show", "arm-pick-place", "--profile", str(path)],
                           env={"COLUMNS": "200"})
    assert result.exit_code == 0 and "calibration: 2026-11-02-cal-0000abcd of 2026-11-02" in result.output
    raw["robot"] = "quadruped-turns"
    path.write_text(yaml.safe_dump(raw))
    result = runner.invoke(app, ["embodiment", "show", "arm-pick-place", "--profile", str(path)])
    assert result.exit_code == 2 and "--profile: " in result.output and "'quadruped-turns'" in result.output
