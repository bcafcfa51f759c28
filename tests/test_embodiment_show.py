"""``cellguard embodiment show``: the text holds what its docstring promises: limits with units, the measured
parameters as written, symmetry pairs and the calibration."""

from __future__ import annotations

from typer.testing import CliRunner

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
