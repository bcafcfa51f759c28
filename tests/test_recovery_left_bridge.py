"""Recoveries over a bridge: refused in one line naming the robot, as faults are.

A retry_grasp over a sim-server serving the arm was refused as "'retry_grasp' cannot run on 'arm-pick-place'; it
needs a cell that can reach, tool_taught, drop_point (pick-place cells can)": the served cell is a pick-place cell.
"""

from __future__ import annotations

import pytest
from sim_server_util import server_counters, start_server
from typer.testing import CliRunner

from cellguard.cli import app


@pytest.fixture(scope="module")
def arm_server():
    proc, port = start_server()
    yield port
    proc.kill()
    proc.wait()


def test_a_recovery_over_a_bridge_says_it_needs_a_simulated_cell_and_names_the_robot(arm_server, tmp_path):
    robot = f"sim-server:udp://127.0.0.1:{arm_server}"
    path = tmp_path / "s.yaml"
    path.write_text(f"cell: arm-pick-place\nrobot: {robot}\ncycle: {{source: input, input: cycle_done}}\n"
                    "acceptance_cycles: 1\nproduction_cycles: 1\n"
                    "recovery:\n  behaviours:\n    - {do: retry_grasp, trigger: grasp_missed, attempts: 2}\n")
    result = CliRunner().invoke(app, ["run", str(path), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2, result.output
    assert result.stderr == (f"error: recovery: runs on simulated cells only (a bridge reports no failed checks to "
                             f"start one); robot {robot!r} is a bridge\n")
    assert not (tmp_path / "out").exists()  # nothing ran, nothing recorded
    assert server_counters(arm_server)["commands"] == 0  # nothing moved
