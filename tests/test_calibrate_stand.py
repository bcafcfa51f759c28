"""A legged cell: excited on a stand its joints are identified; walking, only its drives are."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from cellguard.calibrate.excitation import excitation_scenario, excite
from cellguard.calibrate.identify import identify, load_segments, model_params
from cellguard.calibrate.stand import Stand
from cellguard.calibrate.torque_model import JointTerms, TorqueModel, current_nrmse
from cellguard.cli import app
from cellguard.robot.physics import Physics
from cellguard.robot.registry import make_cell

QUAD = "quadruped-turns"
HIDDEN = Physics(friction={"fl_knee": 1.5}, delay_s=0.003)


@pytest.fixture(scope="module")
def on_stand(tmp_path_factory):
    out = tmp_path_factory.mktemp("stand") / "excite"
    excite(excitation_scenario(QUAD, 6.0), out, physics=HIDDEN, stand=Stand())
    return out


def test_joints_on_a_stand_are_identified(on_stand):
    cell = make_cell(QUAD)
    segments = load_segments([on_stand], cell)
    assert all(s.on_stand for s in segments)
    result = identify(segments, cell, model_params(cell))
    by = {(e["parameter"], e["joint"]): e for e in result["estimates"]}
    assert by[("delay", None)]["value"] == pytest.approx(0.003, abs=1e-3)
    assert by[("friction", "fl_knee")]["value"] == pytest.approx(0.15, rel=0.05)
    assert by[("friction", "fr_knee")]["value"] == pytest.approx(0.10, rel=0.05)
    assert not result["warnings"]
    # the calibrated model predicts the record's currents better than the nominal one
    nominal = current_nrmse(TorqueModel(cell), segments)
    calibrated = current_nrmse(TorqueModel(cell, JointTerms.from_estimates(cell, result["estimates"])), segments)
    knee = TorqueModel(cell).names.index("fl_knee")
    assert calibrated[knee] < 0.5 * nominal[knee]


def test_a_free_base_leaves_joint_terms_unidentified_with_a_warning(on_stand):
    cell = make_cell(QUAD)
    walking = [type(s)(s.q, s.qd, s.q_cmd, s.tau, s.record_id, on_stand=False) for s in load_segments([on_stand], cell)]
    result = identify(walking, cell, model_params(cell))
    joint_terms = [e for e in result["estimates"] if e["parameter"] in ("friction", "armature", "damping")]
    assert joint_terms and all(e["interval"] is None for e in joint_terms)
    assert all(e["note"] == "not identifiable from this data" for e in joint_terms)
    assert any(e["parameter"] == "delay" and e["interval"] for e in result["estimates"])  # the drives still are
    assert "--stand" in result["warnings"][0]
    cli = CliRunner().invoke(app, ["identify", str(on_stand), "--params", "friction"])
    assert cli.exit_code == 0 and "not identifiable" not in cli.output  # the record says: on a stand


def test_stand_refuses_a_fixed_base_cell():
    from cellguard.calibrate.identify import CalibrationError

    with pytest.raises(CalibrationError, match="no floating base"):
        Stand().apply(make_cell("arm-pick-place"))
