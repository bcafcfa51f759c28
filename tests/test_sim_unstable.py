"""A simulated cell whose physics blows up: MuJoCo resets its state (time back to 0) and carries on. The run went
on with time gone back, exited 0, and wrote a record its readers called damaged (7,660 ticks repeating sequence
numbers); now the cell's reads fail as a lost link, the run stops there, named, and its record is whole."""

from __future__ import annotations

import numpy as np
import pytest

from cellguard.record.reader import open_record
from cellguard.robot.protocol import RobotLinkError
from cellguard.robot.registry import make_cell
from cellguard.runtime import run_scenario
from cellguard.scenario import parse_scenario


@pytest.mark.parametrize("steps", [0, 5])  # at 0 s the reset leaves time where it was
@pytest.mark.parametrize("name", ["arm-pick-place", "quadruped-turns"])
def test_a_state_mujoco_resets_fails_every_later_read_and_time_runs_on(name, steps, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cell = make_cell(name)
    for _ in range(steps):
        cell.step()
    before = cell.data.time
    cell.data.qvel[:] = 1e30  # huge: MuJoCo's check resets the state
    cell.step()
    assert cell.data.time > before  # not back to 0
    with pytest.raises(RobotLinkError, match=r"simulation became unstable at .* reset it") as info:
        cell.read()
    assert info.value.lost and info.value.kind == "robot_read_failed"
    assert list(tmp_path.iterdir()) == []  # MuJoCo wrote MUJOCO_LOG.TXT into the working folder


def test_a_payload_the_physics_cannot_carry_stops_the_run_and_the_record_is_whole(tmp_path):
    """+100 g on the arm's 50 g part: MuJoCo blew up 3.2 s into the first cycle that carried it."""
    scenario = parse_scenario({"cell": "arm-pick-place", "seed": 1, "acceptance_cycles": 1, "production_cycles": 3,
                               "process_changes": [{"kind": "payload", "at_cycle": 1, "grams": 100}]})
    summary = run_scenario(scenario, tmp_path / "out")
    assert "simulation became unstable" in summary["stopped"]
    times = [e["t_ns"] for e in summary["events"]]
    assert times == sorted(times)
    with open_record(tmp_path / "out") as record:
        health = record.health()
        assert health.ok and not health.repeats and not any(health.gaps.values()), health
        t_ns = np.asarray(record.ticks(rate="decimated").t_ns)
    assert (np.diff(t_ns) > 0).all()
