"""The tick loop against `cellguard sim-server` in another process, over UDP on 127.0.0.1.

Robot-link faults each become a named event and the scenario's stop category: the server
killed mid-cycle, replies delayed 50 ms, packets dropped past the budget; a NaN chunk never
reaches the wire.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from sim_server_util import HOME, scenario, server_counters, start_server, sway_file

from cellguard.errors import CellguardError
from cellguard.record.reader import open_record
from cellguard.record.writer import RecordConfig
from cellguard.runtime import Run, run_scenario
from cellguard.scenario import parse_scenario


@pytest.fixture
def server(request):
    proc, port = start_server(*getattr(request, "param", ()))
    yield proc, port
    proc.kill()
    proc.wait()


def test_a_bridge_run_follows_the_policy_and_records_wall_time(server, tmp_path):
    _, port = server
    summary = run_scenario(parse_scenario(scenario(port, sway_file(tmp_path / "sway.npz"))), tmp_path / "out")
    assert "stopped" not in summary, summary["events"]
    timing = summary["timing"]
    assert timing["ticks"] > 100  # two seconds paced by the wall clock (1 kHz asked; late ticks on a loaded host)
    cost = timing["recorder_tick_us"]  # what handing each tick to the recorder cost the servo thread
    assert 0.0 < cost["p50"] <= cost["p99"] <= cost["max"] and cost["over_200us"] >= 0
    with open_record(tmp_path / "out") as record:
        ticks = record.ticks()
        assert len(ticks) > 50  # the record keeps a reduced rate between events
        q0 = np.asarray(ticks.q_meas)[:, 0]
    assert q0.max() - q0.min() > 0.01  # the served arm really moved with the policy


def test_server_killed_mid_cycle_stops_within_the_watchdog_and_the_record_names_it(server, tmp_path):
    proc, port = server
    killed = {}

    def kill():  # mid-cycle: once the loop has commanded for 0.3 s (set-up and warm-up take seconds on a loaded host)
        while server_counters(port).get("commands", 0) < 300:
            time.sleep(0.01)
        killed["t_ns"] = time.monotonic_ns()
        proc.kill()

    threading.Thread(target=kill, daemon=True).start()
    summary = run_scenario(parse_scenario(scenario(port, sway_file(tmp_path / "sway.npz"))), tmp_path / "out")
    assert summary["stopped"].startswith("robot link")
    link = [e for e in summary["events"] if e["kind"] in ("robot_read_timeout", "robot_server_gone", "robot_state_stale")]
    assert link and link[0]["category"] == 1  # the scenario's default stop category for a link fault
    watchdog_ns = 0.3e9
    assert link[0]["t_ns"] - killed["t_ns"] < watchdog_ns
    # a category 1 stop cannot brake a robot it no longer reaches: power off at once (the run ended with power on)
    removed = [e for e in summary["events"] if e["kind"] == "power_removed"]
    assert removed and removed[0]["category"] == 0 and "robot link lost" in removed[0]["reason"], summary["events"]
    with open_record(tmp_path / "out") as record:
        kinds = [e.kind for e in record.events()]
    assert link[0]["kind"] in kinds and "power_removed" in kinds


@pytest.mark.parametrize("server", [("--delay-ms", "50")], indirect=True)
def test_replies_delayed_50_ms_are_a_staleness_stop(server, tmp_path):
    _, port = server
    summary = run_scenario(parse_scenario(scenario(port, sway_file(tmp_path / "sway.npz"), stale_s=0.02)),
                           tmp_path / "out")
    stale = [e for e in summary["events"] if e["kind"] == "robot_state_stale"]
    assert stale and stale[0]["category"] == 1
    assert summary["stopped"]
    guard_stops = [e["reason"] for e in summary["events"] if e["kind"] == "protective_stop"]
    assert guard_stops == ["stop asked by the loop: robot link, robot_state_stale: " + stale[0]["reason"]]


@pytest.mark.parametrize("server", [("--drop-every", "4")], indirect=True)
def test_dropped_packets_are_counted_and_stop_past_the_budget(server, tmp_path):
    _, port = server
    summary = run_scenario(parse_scenario(scenario(port, sway_file(tmp_path / "sway.npz"), drop_budget=40,
                                                   stop_category=2)), tmp_path / "out")
    assert summary["timing"]["packets_dropped"] > 40
    dropped = [e for e in summary["events"] if e["kind"] == "robot_packets_dropped"]
    assert len(dropped) == 1 and dropped[0]["category"] == 2
    assert summary["stopped"]


def test_a_nan_chunk_never_reaches_the_wire(server, tmp_path):
    _, port = server
    run = Run(parse_scenario(scenario(port, sway_file(tmp_path / "nan.npz", nan_at_s=0.5))))
    try:
        run.cycle()
        before = run.cell.counters()
        t = run.clock.now()
        run.link.write(t, np.full(6, np.nan))  # straight at the link: refused before the bridge
        with pytest.raises(CellguardError, match="finite"):
            run.cell.write(HOME + np.array([np.nan, 0, 0, 0, 0, 0]))  # the bridge refuses before packing
        time.sleep(0.05)
        after = run.cell.counters()
    finally:
        run.close()
    kinds = [e.kind for e in run.events]
    assert "chunk_rejected" in kinds  # the executor refused the NaN chunks
    assert "setpoint_not_finite" in kinds
    assert before["commands"] > 100 and after["nonfinite_commands"] == 0


def test_a_bridge_that_does_not_answer_is_one_line_and_exit_2(tmp_path):
    from typer.testing import CliRunner

    from cellguard.cli import app
    from sim_server_util import free_port

    path = tmp_path / "s.yaml"
    path.write_text(f"cell: arm-pick-place\nrobot: sim-server:udp://127.0.0.1:{free_port()}\n"
                    "cycle: {source: time, seconds: 1}\n")
    result = CliRunner().invoke(app, ["run", str(path), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2
    assert "does not answer" in result.output and "Traceback" not in result.output
    bad = tmp_path / "b.yaml"
    bad.write_text("cell: arm-pick-place\nrobot: sim-server:udp://10.0.0.5:9000\n")
    result = CliRunner().invoke(app, ["run", str(bad), "--out", str(tmp_path / "out2")])
    assert result.exit_code == 2 and "loopback" in result.output


def test_a_task_cycle_on_a_served_robot_is_refused_before_the_record(server, tmp_path):
    """The served robot has no task of its own: refused before --out is created (a partial record blocked it)."""
    from typer.testing import CliRunner

    from cellguard.cli import app

    _, port = server
    path = tmp_path / "s.yaml"
    path.write_text(f"cell: arm-pick-place\nrobot: sim-server:udp://127.0.0.1:{port}\ncycle: {{source: task}}\n")
    result = CliRunner().invoke(app, ["run", str(path), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2 and result.stderr.startswith("error: cycle.source: 'task' needs a simulated cell")
    assert result.stderr.count("\n") == 1 and not (tmp_path / "out").exists()


@pytest.mark.parametrize("option, value", [
    ("--duration-s", "inf"), ("--duration-s", "nan"), ("--duration-s", "-1"), ("--duration-s", "0"),
    ("--delay-ms", "nan"), ("--delay-ms", "1e308"), ("--delay-ms", "-1"), ("--drop-every", "-1"), ("--seed", "-1"),
    ("--seed", str(2**64)),
])
def test_a_sim_server_option_out_of_range_is_one_line_and_exit_2(option, value):
    """NaN and infinities raised inside the server (OverflowError, ValueError); -1 s ran and exited 0."""
    from typer.testing import CliRunner

    from cellguard.cli import app

    args = ["sim-server", "arm-pick-place", "--port", "9", option, value]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2, result.output
    assert result.stderr.startswith(f"error: {option}: must be in ") and result.stderr.count("\n") == 1


@pytest.mark.parametrize("server", [("--drop-every", "10")], indirect=True)
def test_every_tick_is_recorded_when_the_robot_sends_no_new_state(server, tmp_path):
    """A lost state packet repeats the last state's stamp; ticks stamped with it were taken for copies by the
    reader (2 % of a sim-server run's ticks lost, and setpoint steps across them read as twice the speed limit)."""
    _, port = server
    every_tick = RecordConfig(decimated_hz=1000.0)  # a run without events keeps no full-rate window to read
    summary = run_scenario(parse_scenario(scenario(port, sway_file(tmp_path / "sway.npz"), drop_budget=1_000_000)),
                           tmp_path / "out", record=every_tick)
    assert summary["timing"]["packets_dropped"] > 20
    with open_record(tmp_path / "out") as record:
        t_ns = np.asarray(record.ticks(rate="decimated").t_ns)
    assert len(t_ns) >= summary["timing"]["ticks"] and (np.diff(t_ns) > 0).all()


def test_power_removed_on_a_served_robot_ends_the_run_and_is_never_switched_back_on(server, tmp_path):
    """Every chunk is NaN, so none is taken: the no-first-chunk watchdog's category 1 stop removes power. A
    simulated shift's operator resets the cell at the next cycle; a robot behind a bridge waits for a person."""
    _, port = server
    raw = scenario(port, sway_file(tmp_path / "nan.npz", nan_at_s=0.0))
    raw.update(production_cycles=1, guard={"watchdog_s": 0.2, "watchdog_category": 1})
    summary = run_scenario(parse_scenario(raw), tmp_path / "out")
    kinds = [e["kind"] for e in summary["events"]]
    assert "power_removed" in kinds and "reset" not in kinds, kinds
    assert summary["stopped"].startswith("power removed by a category 1 stop (stop asked by the loop: "
                                         "watchdog_no_first_chunk)"), summary["stopped"]
    assert len(summary["cycles"]) == 1


def test_the_server_killed_during_the_last_retreat_stops_the_run(server, tmp_path):
    """The retreat was aborted by the link fault and the run still exited 0 with no word of it."""
    proc, port = server
    raw = scenario(port, sway_file(tmp_path / "sway.npz"))
    raw["cycle"]["seconds"] = 2.5  # the sway's far end, 0.1 rad from home: a retreat to play
    run = Run(parse_scenario(raw))

    def kill():
        while not any(e.kind == "retreat_begin" for e in list(run.events)):
            time.sleep(0.002)
        proc.kill()

    threading.Thread(target=kill, daemon=True).start()
    summary = run_scenario(run.scenario, tmp_path / "out", run=run)
    kinds = [e["kind"] for e in summary["events"]]
    assert "retreat_aborted" in kinds or "retreat_done" not in kinds, kinds
    assert summary["stopped"].startswith("robot link: robot_"), summary.get("stopped")
