"""A stopped run's line says what stopped it and where the robot was left. An operator stop whose retreat a second
signal aborted said only "stopped by the operator: operator stop (SIGINT); the record in DIR is complete", the robot
held away from home; a retreat not played and a power-off in the last cycle read "the cell was stopped (stop)", no
cause (the safety controller's input has no event of its own, a retreat not played no stop at all)."""

from __future__ import annotations

import signal

import mujoco
import numpy as np
import pytest
import typer

from cellguard.cli.errors import exit_if_stopped
from cellguard.control.settings import build_guard
from cellguard.robot.protocol import SafetyInputs
from cellguard.runtime import Run, run_scenario
from cellguard.scenario import parse_scenario

# the tool point 18 mm above the table: the joint-space way home from there leaves the workspace box
LOW = np.array([0.297, -1.559, -2.31, -1.096, -0.604, 0.025])


def _line(run: Run, out, capsys) -> tuple[str, int]:
    """``run`` through ``run_scenario`` into ``out``; the command's stderr line for it and its exit code."""
    summary = run_scenario(run.scenario, out, run=run)
    capsys.readouterr()
    with pytest.raises(typer.Exit) as ended:
        exit_if_stopped(summary, out)
    return capsys.readouterr().err.strip(), ended.value.exit_code


def test_an_operator_stop_whose_retreat_a_second_signal_aborted_says_the_robot_is_away_from_home(tmp_path, capsys):
    run = Run(parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 3}))
    write, writes = run.cell.write, []

    def pressed(setpoint):  # the operator presses mid-motion, then again well into the retreat
        writes.append(int(run.events.has("retreat_begin")))
        if len(writes) == 1500 or (writes[-1] and writes.count(1) == 150):
            signal.raise_signal(signal.SIGINT)
        return write(setpoint)

    run.cell.write = pressed
    line, code = _line(run, tmp_path / "run", capsys)
    assert code == 130
    assert line == (f"stopped by the operator: operator stop (SIGINT); the record in {tmp_path / 'run'} is complete; "
                    "robot: held away from home, power on (retreat_aborted, category 2)")


def test_a_retreat_not_played_is_named_and_says_the_robot_is_away_from_home(tmp_path, capsys):
    np.savez(tmp_path / "hold.npz", t=np.arange(40) * 0.1, actions=np.tile(LOW, (40, 25, 1)), dt=np.float64(0.02))
    run = Run(parse_scenario({"cell": "arm-pick-place", "seed": 1, "policy": f"replay:{tmp_path / 'hold.npz'}",
                              "acceptance_cycles": 1, "production_cycles": 0,
                              "cycle": {"source": "time", "seconds": 3}}))
    cell = run.cell
    cell.data.qpos[cell.drives.qadr] = LOW  # the arm there already: no approach
    cell.write(LOW)
    mujoco.mj_forward(cell.model, cell.data)
    run.guard = build_guard(cell, run.scenario.guard)
    line, code = _line(run, tmp_path / "run", capsys)
    assert code == 1
    assert line.startswith("error: the cell was stopped (retreat_aborted): the retreat home was not played: ")
    assert line.endswith(f"; robot: held away from home, power on (retreat_aborted); {tmp_path / 'run'}/summary.json "
                         "says what ran")


@pytest.mark.parametrize("category", [0, 1])
def test_a_power_off_in_the_last_cycle_names_the_safety_controllers_stop_and_the_robot_left_unpowered(
        tmp_path, capsys, category):
    run = Run(parse_scenario({"cell": "arm-pick-place", "seed": 3, "acceptance_cycles": 1, "production_cycles": 0,
                              "cycle": {"source": "time", "seconds": 2.5}}))
    cell = run.cell
    cell.safety = lambda: SafetyInputs(stop=category if 1.0 <= cell.t_ns * 1e-9 < 1.1 else None)  # its stop input
    line, code = _line(run, tmp_path / "run", capsys)
    assert code == 1
    assert line == (f"error: the cell was stopped (protective_stop): power removed by a category {category} stop "
                    "(safety controller protective stop input); reset the cell and start a new run; robot: left where "
                    f"it stopped, power off, not retreated home (power_removed, category {category}); "
                    f"{tmp_path / 'run'}/summary.json says what ran")


@pytest.mark.parametrize("stopped, events, left", [
    ("operator stop (SIGTERM)", [("operator_stop", 2), ("protective_stop", 2), ("retreat_begin", None),
                                 ("retreat_done", None)], "robot: home (retreat_done)"),
    # power removed in an earlier cycle, then the operator's reset: that power-off says nothing of the end
    ("operator stop (SIGTERM)", [("protective_stop", 0), ("power_removed", 0), ("reset", None), ("operator_stop", 2),
                                 ("protective_stop", 2)], "robot: no retreat played (home already, or no home pose)"),
    # a link fault: the loop moves nothing after it
    ("robot link: stale", [("robot_state_stale", 2), ("protective_stop", 2)],
     "robot: held where it stopped, not retreated home (no motion after robot_state_stale, category 2)"),
])
def test_where_the_robot_was_left_is_read_from_the_runs_last_events(tmp_path, capsys, stopped, events, left):
    summary = {"stopped": stopped, "events": [{"t_ns": i, "kind": kind, "reason": "stop asked by the loop: x",
                                               **({} if c is None else {"category": c})}
                                              for i, (kind, c) in enumerate(events)]}
    with pytest.raises(typer.Exit):
        exit_if_stopped(summary, tmp_path)
    assert f"; {left}" in capsys.readouterr().err
