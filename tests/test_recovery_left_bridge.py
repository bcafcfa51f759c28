"""Recoveries over a bridge: refused with the scenario, in one line naming the robot, as faults are.

A retry_grasp over a sim-server serving the arm was refused as the run started, after the bridge had connected, as
"'retry_grasp' cannot run on 'arm-pick-place'; it needs a cell that can reach, tool_taught, drop_point (pick-place
cells can)": the served cell is a pick-place cell. With no server there, it said to start one.
"""

from __future__ import annotations

from typer.testing import CliRunner

from cellguard.cli import app


def test_a_recovery_over_a_bridge_is_refused_with_the_scenario_naming_the_robot(tmp_path):
    robot = "sim-server:udp://127.0.0.1:9"  # nothing serves there: refused before any connection is tried
    path = tmp_path / "s.yaml"
    path.write_text(f"cell: arm-pick-place\nrobot: {robot}\ncycle: {{source: input, input: cycle_done}}\n"
                    "acceptance_cycles: 1\nproduction_cycles: 1\n"
                    "recovery:\n  behaviours:\n    - {do: retry_grasp, trigger: grasp_missed, attempts: 2}\n")
    result = CliRunner().invoke(app, ["run", str(path), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2, result.output
    assert " ".join(result.stderr.split()) == (f"error: {path}: recovery: runs on simulated cells only (a bridge "
                                               f"reports no failed check to start one); robot {robot!r} is a bridge")
    assert not (tmp_path / "out").exists()  # nothing ran, nothing recorded
