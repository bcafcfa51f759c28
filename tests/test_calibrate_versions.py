"""identify --write versions a calibration: a calibrated MJCF beside the profile, a version id every later
record's context carries, and older versions (profiles, MJCFs, records) kept readable."""

from __future__ import annotations

import mujoco
import pytest
from typer.testing import CliRunner

from cellguard.calibrate.excitation import excitation_scenario, excite
from cellguard.cli import app
from cellguard.embodiment import load_profile
from cellguard.errors import ProfileError
from cellguard.record.reader import open_record
from cellguard.robot.arm_cell import ASSETS
from cellguard.robot.physics import Physics
from cellguard.robot.registry import make_cell
from cellguard.runtime.loop import Run, run_scenario
from cellguard.scenario import Scenario

ARM = "arm-pick-place"
runner = CliRunner()


@pytest.fixture(scope="module")
def excited(tmp_path_factory):
    out = tmp_path_factory.mktemp("versions") / "excite"
    excite(excitation_scenario(ARM, 6.0), out, physics=Physics(friction={"elbow": 1.5}, armature=0.7))
    return out


def context(out):
    with open_record(out / "record.mcap" if (out / "record.mcap").exists() else out) as rec:
        return rec.context


def one_cycle(out, calibration=None):
    run_scenario(Scenario(cell=ARM, acceptance_cycles=1, production_cycles=0, calibration=calibration), out)
    return context(out)


def write(record, profile):
    result = runner.invoke(app, ["identify", str(record), "--params", "friction,damping,armature",
                                 "--write", str(profile)])
    assert result.exit_code == 0, result.output
    return load_profile(make_cell(ARM).model, profile)


def test_write_then_runs_carry_the_version_and_old_versions_stay(excited, tmp_path):
    profile = tmp_path / "arm_profile.yaml"
    profile.write_bytes((ASSETS / "arm_profile.yaml").read_bytes())
    before = one_cycle(tmp_path / "before")
    assert "calibration" not in before["embodiment"]

    first = write(excited, profile)
    v1 = first.calibration.version
    assert first.version == v1 and v1.startswith(first.calibration.date) and "-cal-" in v1
    assert first.calibration.previous == "2026-11-01" and first.calibration.records
    mjcf1 = tmp_path / first.calibration.mjcf
    assert mjcf1.name == f"arm_profile.{v1}.xml"
    model = mujoco.MjModel.from_xml_path(str(mjcf1))  # the calibrated MJCF loads and has the measured values
    elbow = next(m for m in first.measured if m.joint == "elbow" and m.parameter == "friction")
    dof = model.jnt_dofadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "elbow")]
    assert model.dof_frictionloss[dof] == pytest.approx(elbow.value, rel=1e-5)
    assert elbow.value == pytest.approx(0.3, rel=0.1)

    during = one_cycle(tmp_path / "v1", calibration=profile)
    assert during["embodiment"]["version"] == v1
    assert during["embodiment"]["calibration"]["version"] == v1
    assert during["embodiment"]["calibration"]["mjcf"] == mjcf1.name

    mjcf1_bytes = mjcf1.read_bytes()
    second = write(excited, profile)
    v2 = second.calibration.version
    assert v2 != v1 and second.calibration.previous == v1
    assert mjcf1.read_bytes() == mjcf1_bytes and (tmp_path / f"arm_profile.{v2}.xml").is_file()
    kept = load_profile(make_cell(ARM).model, tmp_path / f"arm_profile.{v1}.yaml")
    assert kept.calibration.version == v1 and kept.sha256 == first.sha256
    assert load_profile(make_cell(ARM).model, tmp_path / "arm_profile.2026-11-01.yaml").calibration is None
    assert one_cycle(tmp_path / "v2", calibration=profile)["embodiment"]["calibration"]["version"] == v2

    # records made under earlier versions still read, each naming its own
    assert context(tmp_path / "v1")["embodiment"]["calibration"]["version"] == v1
    assert "calibration" not in context(tmp_path / "before")["embodiment"]


def test_a_calibration_of_another_robot_is_refused(tmp_path):
    quad = tmp_path / "quad.yaml"
    quad.write_bytes((ASSETS / "quadruped_profile.yaml").read_bytes())
    with pytest.raises(ProfileError, match="^calibration: "):
        Run(Scenario(cell=ARM, calibration=quad))
