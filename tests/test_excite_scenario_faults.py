"""``excite`` from a scenario with faults or process changes is refused: they were dropped silently, so an
excitation of a scenario with an elbow friction x2 and a 200 g payload recorded the nominal robot, its summary's
ground truth said no faults, and identify reported the nominal robot as that scenario's."""

from __future__ import annotations

import pytest
import yaml
from cli_util import one_error
from typer.testing import CliRunner

from cellguard.calibrate.excitation import excitation_scenario
from cellguard.cli import app
from cellguard.errors import ScenarioError
from cellguard.scenario import parse_scenario

runner = CliRunner()
FAULT = {"kind": "friction_step", "joint": "elbow", "at_cycle": 0, "factor": 2.0}
PAYLOAD = {"kind": "payload", "at_cycle": 0, "grams": 200}


@pytest.mark.parametrize("extra, named", [
    ({"faults": [FAULT]}, "faults"),
    ({"process_changes": [PAYLOAD]}, "process_changes"),
    ({"faults": [FAULT], "process_changes": [PAYLOAD]}, "faults, process_changes"),
])
def test_a_scenario_with_faults_or_process_changes_is_refused(extra, named):
    scenario = parse_scenario({"cell": "arm-pick-place", "seed": 2, **extra})
    with pytest.raises(ScenarioError) as refused:
        excitation_scenario(scenario, 7.0)
    assert str(refused.value).startswith(f"{named}: an excitation injects none"), refused.value


def test_a_scenario_without_them_keeps_its_robot_guard_and_seed():
    scenario = parse_scenario({"cell": "arm-pick-place", "seed": 2, "guard": {"reduced_speed": 0.2}})
    excitation = excitation_scenario(scenario, 7.0)
    assert (excitation.cell, excitation.seed, excitation.guard) == (scenario.cell, 2, scenario.guard)
    assert (excitation.policy, excitation.total_cycles, excitation.cycle.seconds) == ("excite", 1, 7.0)


def test_the_cli_refuses_in_one_line_and_records_nothing(tmp_path):
    path = tmp_path / "faulty.yaml"
    path.write_text(yaml.safe_dump({"cell": "arm-pick-place", "faults": [FAULT], "process_changes": [PAYLOAD]}))
    out = tmp_path / "ex"
    line = one_error(runner.invoke(app, ["excite", str(path), "--seconds", "7", "--out", str(out)]))
    assert line.startswith(f"error: {path}: faults, process_changes: an excitation injects none"), line
    assert not out.exists()
