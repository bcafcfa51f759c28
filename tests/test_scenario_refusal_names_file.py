"""A scenario refused against its cell (a trigger the cell does not report, a behaviour it cannot run, a late recovery
with no recovery) names the file, as a refusal while it is read does; a negative --seed names --seed."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from cellguard.cli import app


@pytest.mark.parametrize(("body", "key"), [
    ("cell: arm-pick-place\nfaults:\n  - {kind: intermittent_slip, rate: 1.0, dx_mm: -5.0}\nrecovery:\n"
     "  behaviours:\n    - {do: retry_grasp, trigger: grasp_mised}\n", "recovery.behaviours[0].trigger: "),
    ("cell: quadruped-turns\nrecovery:\n  behaviours:\n    - {do: rehome, trigger: grasp_missed}\n",
     "recovery.behaviours[0].do: "),
    ("cell: arm-pick-place\nfaults:\n  - {kind: late_recovery, at_cycle: 0, speed_scale: 0.5}\n",
     "faults[0].kind: "),
], ids=["a trigger the cell does not report", "a behaviour the cell cannot run", "a late recovery with no recovery"])
def test_a_scenario_refused_against_its_cell_names_its_file(tmp_path, body, key):
    scenario = tmp_path / "s.yaml"
    scenario.write_text("acceptance_cycles: 1\nproduction_cycles: 0\n" + body)
    result = CliRunner().invoke(app, ["run", str(scenario), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2 and result.stderr.startswith(f"error: {scenario}: {key}")
    assert result.stderr.strip().count("\n") == 0 and not (tmp_path / "out").exists()


def test_a_negative_seed_names_the_option(tmp_path):
    model = tmp_path / "p.onnx"
    result = CliRunner().invoke(app, ["train-demo-policy", "-o", str(model), "--seed", "-1"])
    assert result.exit_code == 2 and "'--seed'" in result.stderr and "scenario" not in result.stderr
    assert not model.exists()
