"""Scenarios refused before anything runs: a fault that can never act, a payload that leaves the part no mass.

A ``late_recovery`` fault on a scenario with no ``recovery:`` section ran (exit 0) and was listed in the ground
truth, though no recovery ever ran for it to slow. A payload of -100 g on the 50 g part made its mass negative
and the part flew 12 m, exit 0.
"""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import ScenarioError
from cellguard.runtime import Run
from cellguard.scenario import parse_scenario


def _run(**patch):
    return Run(parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 2, **patch}))


def test_a_late_recovery_fault_without_recoveries_is_refused_on_the_command_line(tmp_path):
    scenario = tmp_path / "s.yaml"
    scenario.write_text("cell: arm-pick-place\nproduction_cycles: 1\n"
                        "faults:\n  - {kind: late_recovery, at_cycle: 0, speed_scale: 0.5}\n")
    result = CliRunner().invoke(app, ["run", str(scenario), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2 and result.stderr.strip().count("\n") == 0
    assert "faults[0].kind: 'late_recovery'" in result.stderr and "no recovery: section" in result.stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(("changes", "named"), [
    ([{"kind": "payload", "at_cycle": 1, "grams": -100}], "process_changes[0]: from cycle 1"),
    ([{"kind": "payload", "at_cycle": 0, "grams": -30}, {"kind": "payload", "at_cycle": 2, "grams": -30}],
     "process_changes[1]: from cycle 2"),  # each on its own leaves 20 g; together -10 g
    ([{"kind": "payload", "at_cycle": 0, "grams": -50}], "process_changes[0]: from cycle 0"),  # exactly nothing
])
def test_a_payload_that_leaves_the_part_no_mass_is_refused_naming_the_entry(changes, named):
    with pytest.raises(ScenarioError) as info:
        _run(process_changes=changes)
    assert named in str(info.value) and "the part would weigh" in str(info.value) and "\n" not in str(info.value)


def test_a_lighter_part_that_still_weighs_something_runs():
    run = _run(process_changes=[{"kind": "payload", "at_cycle": 0, "grams": 60},
                                {"kind": "payload", "at_cycle": 1, "grams": -100}])  # 50 + 60 - 100 = 10 g
    run.close()
