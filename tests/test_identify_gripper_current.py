"""identify needs motor current on the joints it fits, not on a gripper: an arm whose gripper servo senses no
current (every reading NaN) was refused with "no stretch of 200 ticks at the servo rate; record at full rate",
of a record made at full rate. A fitted joint without current is refused naming it."""

from __future__ import annotations

import json

import numpy as np
import pytest
from cli_util import one_error
from typer.testing import CliRunner

from cellguard.calibrate.excitation import ExcitationPolicy, excitation_scenario
from cellguard.cli import app
from cellguard.record.writer import RecordConfig
from cellguard.robot.registry import make_cell
from cellguard.runtime.loop import Run, run_scenario

ARM = "arm-pick-place"
runner = CliRunner()


def record_without_current(out, joint: str, seconds: float):
    """A full-rate excitation of the arm whose ``joint``'s drive reports no current."""
    cell = make_cell(ARM)
    column = cell.profile.joint_names.index(joint)
    scenario = excitation_scenario(ARM, seconds)
    run = Run(scenario, policy_factory=lambda: ExcitationPolicy.for_profile(cell.profile, cell.q_home,
                                                                            hold=("gripper",)))
    read = run.cell.drives.read

    def unsensed(t_ns):
        state = read(t_ns)
        state.current[column] = np.nan
        return state

    run.cell.drives.read = unsensed
    run_scenario(scenario, out, run=run, record=RecordConfig(decimated_hz=1e9 / run.cell.dt_ns))
    return out


@pytest.fixture(scope="module")
def no_gripper_current(tmp_path_factory):
    return record_without_current(tmp_path_factory.mktemp("gripper") / "ex", "gripper", 3.0)


def test_a_gripper_without_current_sensing_is_identified(no_gripper_current):
    result = runner.invoke(app, ["identify", str(no_gripper_current), "--params", "friction,kp", "--json"])
    assert result.exit_code == 0, result.output
    out = json.loads(result.stdout)
    assert out["samples"] > 2500  # every tick of the excitation, none dropped for the gripper's NaN
    hinges = [j.name for j in make_cell(ARM).profile.joints if j.kind == "hinge"]
    assert {e["joint"] for e in out["estimates"] if e["parameter"] == "kp"} == set(hinges)
    assert all(np.isfinite(e["value"]) for e in out["estimates"] if e["interval"] is not None)
    friction = [e for e in out["estimates"] if e["parameter"] == "friction" and e["interval"] is not None]
    assert len(friction) == len(hinges)
    assert all(lo <= e["nominal"] <= hi for e in friction for lo, hi in [e["interval"]]), friction


def test_a_fitted_joint_without_current_is_named(tmp_path):
    out = record_without_current(tmp_path / "ex", "elbow", 1.0)
    line = one_error(runner.invoke(app, ["identify", str(out)]))
    assert line == (f"error: {out}: the record has no motor current on elbow; identification needs the current of "
                    "every joint it fits"), line
