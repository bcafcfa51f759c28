"""A scenario's cell against the cell a real ``cellguard sim-server`` serves.

The run used to take whatever the server served: a scenario naming the quadruped (or no cell at all) drove and
guarded the served arm, and its summary named the scenario's cell beside a context naming the arm.
"""

from __future__ import annotations

import pytest
from sim_server_util import server_counters, served
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.robot.bridges.sim_server import SimServerRobot


@pytest.fixture(scope="module")
def arm_server():
    with served() as port:
        yield port


@pytest.mark.parametrize("cell", ["quadruped-turns", "nope-cell"])
def test_a_scenario_naming_another_cell_than_the_server_serves_is_one_line_and_exit_2(arm_server, cell, tmp_path):
    port = arm_server
    path = tmp_path / "s.yaml"
    path.write_text(f"cell: {cell}\nrobot: sim-server:udp://127.0.0.1:{port}\npolicy: scripted\n"
                    "cycle: {source: input, input: cycle_done}\nacceptance_cycles: 2\nproduction_cycles: 0\n")
    result = CliRunner().invoke(app, ["run", str(path), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2, result.output
    assert result.stderr == (f"error: cell: the scenario names {cell!r} but the sim-server at 127.0.0.1:{port} "
                             "serves 'arm-pick-place'; name the served cell, or serve the scenario's\n")
    assert not (tmp_path / "out").exists()  # nothing ran, nothing recorded
    assert server_counters(port)["commands"] == 0  # nothing moved
    SimServerRobot(("127.0.0.1", port), cell="arm-pick-place").close()  # said goodbye: the next run is let in at once
