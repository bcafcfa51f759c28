"""A calibrated MJCF edited by hand to a term no arm has is refused in one line naming the file, the field and its
plausible range (exit 2), by every command that reads it; nothing is written. A 1e30 kg payload was held by an
``--only`` re-fit that then stored friction 8e70 N*m; a NaN mass was read as the 4 mg its 1 mm sphere weighs by
density, and a 0 kg one dropped the payload, each written as a new calibration (exit 0)."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ElementTree
from dataclasses import replace
from pathlib import Path

import pytest
from cli_util import one_error
from typer.testing import CliRunner

from cellguard.calibrate.excitation import excitation_scenario, excite
from cellguard.calibrate.identify import CalibrationError
from cellguard.calibrate.mjcf import PAYLOAD_BODY, calibrated_mjcf
from cellguard.calibrate.torque_model import JointTerms
from cellguard.cli import app
from cellguard.robot.arm_cell import ASSETS
from cellguard.robot.physics import Physics
from cellguard.robot.registry import make_cell

ARM = "arm-pick-place"
runner = CliRunner()


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """(record, folder): an excitation with 0.2 kg at the tool, and a folder holding the arm's profile calibrated
    from it with that payload."""
    root = tmp_path_factory.mktemp("plausible")
    excite(excitation_scenario(ARM, 8.0), root / "excite", physics=Physics(payload_kg=0.2))
    (root / "cal").mkdir()
    (root / "cal" / "arm_profile.yaml").write_bytes((ASSETS / "arm_profile.yaml").read_bytes())
    result = runner.invoke(app, ["identify", str(root / "excite"), "--write", str(root / "cal" / "arm_profile.yaml"),
                                 "--json"])
    assert result.exit_code == 0, result.output
    assert ElementTree.parse(json.loads(result.stdout)["mjcf"]).find(f".//body[@name='{PAYLOAD_BODY}']") is not None
    return root / "excite", root / "cal"


def edited_copy(calibrated, tmp_path, edit) -> tuple[Path, Path]:
    """A copy of the calibrated folder whose MJCF ``edit(root)`` changed: (profile, MJCF)."""
    folder = tmp_path / "cal"
    folder.mkdir()
    for p in calibrated[1].iterdir():
        (folder / p.name).write_bytes(p.read_bytes())
    mjcf = folder / next(line.split()[1] for line in (folder / "arm_profile.yaml").read_text().splitlines()
                         if line.startswith("model:"))
    tree = ElementTree.parse(mjcf)
    edit(tree.getroot())
    tree.write(mjcf)
    return folder / "arm_profile.yaml", mjcf


def payload_mass(value):
    return lambda root: root.find(f".//body[@name='{PAYLOAD_BODY}']/geom").set("mass", value)


def joint(name, attribute, value):
    return lambda root: root.find(f".//joint[@name='{name}']").set(attribute, value)


def payload_inertia(root):
    root.find(f".//body[@name='{PAYLOAD_BODY}']").insert(
        0, ElementTree.Element("inertial", pos="0 0 0", mass="0.2", diaginertia="1e9 1e9 1e9"))


CASES = [
    (payload_mass("1e30"), "body calibrated_payload geom mass 1e+30 kg is outside the plausible (0, 19.4] kg"),
    (payload_mass("1e4"), "body calibrated_payload geom mass 10000 kg is outside the plausible (0, 19.4] kg"),
    (payload_mass("-1"), "body calibrated_payload geom mass -1 kg is outside the plausible (0, 19.4] kg"),
    (payload_mass("0"), "body calibrated_payload geom mass 0 kg is outside the plausible (0, 19.4] kg"),
    (payload_mass("inf"), "body calibrated_payload geom mass inf kg is outside the plausible (0, 19.4] kg"),
    (payload_mass("nan"), "geom of body calibrated_payload mass 'nan' is not a number"),
    (payload_inertia, "body calibrated_payload inertial diaginertia[0] 1e+09 kg*m^2 is outside the plausible "
                      "[0, 77.6] kg*m^2"),
    (joint("elbow", "damping", "1e30"), "joint elbow damping 1e+30 N*m*s/rad is outside the plausible [0, 10000] "
                                        "N*m*s/rad"),
    (joint("elbow", "frictionloss", "1e30"), "joint elbow frictionloss 1e+30 N*m is outside the plausible [0, 20] N*m"),
    (joint("elbow", "frictionloss", "-0.1"), "joint elbow frictionloss -0.1 N*m is outside the plausible [0, 20] N*m"),
    (joint("wrist_flex", "armature", "1e30"), "joint wrist_flex armature 1e+30 kg*m^2 is outside the plausible "
                                              "[0, 1000] kg*m^2"),
]


@pytest.mark.parametrize(("edit", "said"), CASES)
def test_an_implausible_calibrated_mjcf_is_refused_naming_file_and_field(calibrated, tmp_path, edit, said):
    profile, mjcf = edited_copy(calibrated, tmp_path, edit)
    before = sorted((p.name, p.read_bytes()) for p in profile.parent.iterdir())
    line = one_error(runner.invoke(app, ["identify", str(calibrated[0]), "--only", "elbow,friction", "--write",
                                         str(profile)]))
    assert line.startswith(f"error: --write: {mjcf} ({profile}'s calibrated MJCF): {said}"), line
    assert sorted((p.name, p.read_bytes()) for p in profile.parent.iterdir()) == before  # nothing written
    line = one_error(runner.invoke(app, ["replay", str(calibrated[0]), "--cycle", "0", "--profile", str(profile),
                                         "-o", str(tmp_path / "replay.html")]))
    assert line.startswith(f"error: --profile: {mjcf} ({profile}'s calibrated MJCF): {said}"), line


def test_a_fit_never_writes_a_payload_a_read_would_refuse():
    cell = make_cell(ARM)
    with pytest.raises(CalibrationError, match=r"^--write: the calibrated MJCF of arm-pick-place: body "
                                               r"calibrated_payload geom mass 3000 kg is outside the plausible"):
        calibrated_mjcf(cell, replace(JointTerms.nominal(cell), payload_kg=3000.0))
