"""Ctrl-C (SIGINT), SIGTERM or a closed terminal's SIGHUP while the cycles run: a category 2 stop, the retreat, a
complete record; exit 130. SIGHUP ended the process mid-motion, with no summary and no word on stderr."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable

import mujoco
import numpy as np
import pytest
import yaml

from release_helpers import CELL, cli, two_runs_at_sim

from cellguard.control.settings import build_guard
from cellguard.record.reader import open_record
from cellguard.release import Store
from cellguard.release.log import entries
from cellguard.robot.registry import make_cell
from cellguard.runtime import Run
from cellguard.runtime.operator_stop import OperatorStop
from cellguard.runtime.transitions import TOLERANCE
from cellguard.scenario import parse_scenario


def _signal_mid_run(args: list[str], out, signum: int, group: bool = False) -> str:
    """Run a cellguard command in its own process, send ``signum`` once its record is being written (to its
    whole process group, as a terminal or a service manager does, if ``group``); its stderr."""
    proc = subprocess.Popen([sys.executable, "-c", "from cellguard.cli import app; app()", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=group)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not ((out / "record.mcap").exists()
                                               and (out / "record.mcap").stat().st_size > 100_000):
        time.sleep(0.02)  # the ticks are being written: the loop runs
    if group:
        os.killpg(proc.pid, signum)
    else:
        proc.send_signal(signum)
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    return stderr


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_a_stop_signal_mid_run_stops_the_arm_retreats_it_and_the_record_says_so(tmp_path, signum):
    scenario = tmp_path / "scenario.yaml"
    scenario.write_text(yaml.safe_dump({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 30}))
    out = tmp_path / "run"
    stderr = _signal_mid_run(["run", str(scenario), "--out", str(out), "--json"], out, signum)
    name = signal.Signals(signum).name
    assert stderr.strip().splitlines()[-1].startswith(f"stopped by the operator: operator stop ({name})")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["stopped"] == f"operator stop ({name})"
    assert len(summary["cycles"]) < 31  # the run ended early
    kinds = [e["kind"] for e in summary["events"]]
    assert kinds[:1] == ["operator_stop"] and summary["events"][0]["category"] == 2
    # the guard's stop names the loop's request, not the safety controller's input (which never fired)
    assert [e["reason"] for e in summary["events"] if e["kind"] == "protective_stop"] == [
        f"stop asked by the loop: operator stop ({name})"]
    with open_record(out, strict=True) as rec:
        assert rec.health().finished
        events = {e.kind: e for e in rec.events()}
        assert set(kinds) <= set(events)
        retreat = events.get("retreat_begin")
        held = rec.ticks(start_ns=events["operator_stop"].t_ns, end_ns=retreat.t_ns if retreat else None)
    assert len(held) > 0 and np.abs(held.qd_meas[-1]).max() < 0.05  # at standstill before the retreat
    # the retreat to home follows unless the stop came between cycles, where the arm is home already
    away = np.abs(held.q_meas[-1] - make_cell("arm-pick-place").q_home).max() > TOLERANCE
    assert kinds[-2:] == (["retreat_begin", "retreat_done"] if away else ["operator_stop", "protective_stop"])


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_a_stop_signal_to_the_whole_group_on_wall_time_keeps_the_record_to_the_end_of_the_retreat(tmp_path, signum):
    """A service manager's stop (or a closed terminal) signals the recorder's process too: it must not finish the
    file on it (it did, in the feeder's first pause, and the loop then failed with ``record_failed`` before its stop
    was recorded; on SIGHUP the writer died)."""
    scenario = tmp_path / "scenario.yaml"
    scenario.write_text(yaml.safe_dump({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 30}))
    out = tmp_path / "run"
    stderr = _signal_mid_run(["run", str(scenario), "--out", str(out), "--realtime"], out, signum, group=True)
    name = signal.Signals(signum).name
    assert stderr.strip().splitlines()[-1].startswith(f"stopped by the operator: operator stop ({name})")
    with open_record(out, strict=True) as rec:
        kinds = [e.kind for e in rec.events()]
    assert "operator_stop" in kinds and "record_failed" not in kinds and "run_process_lost" not in kinds


def test_ctrl_c_during_an_excitation_says_so_and_exits_130(tmp_path):
    out = tmp_path / "excite"
    stderr = _signal_mid_run(["excite", "arm-pick-place", "--seconds", "120", "--out", str(out)], out, signal.SIGINT)
    assert "excitation recorded" not in stderr and stderr.strip().splitlines()[-1].startswith(
        f"stopped by the operator: operator stop (SIGINT); the record in {out} is complete")
    assert json.loads((out / "summary.json").read_text())["stopped"] == "operator stop (SIGINT)"


def _run_pressing(run: Run, press: Callable[[list[int]], bool], setpoints: list | None = None) -> list[int]:
    """Run the cycles, raising SIGINT at a setpoint write when ``press(writes)`` says so; ``writes``: per write so
    far, 1 once the retreat has begun, else 0; each setpoint written is appended to ``setpoints``."""
    write, writes = run.cell.write, []

    def write_and_press(setpoint):
        writes.append(int(run.events.has("retreat_begin")))
        if setpoints is not None:
            setpoints.append(np.array(setpoint))
        if press(writes):
            signal.raise_signal(signal.SIGINT)
        return write(setpoint)

    run.cell.write = write_and_press
    try:
        run.run_cycles()
    finally:
        run.close()
    return writes


def _brakes_and_holds(run: Run, setpoints: list) -> None:
    """The setpoints after an abort slow down under the velocity limit to a standstill (never a step)."""
    steps = np.abs(np.diff(np.array(setpoints), axis=0)) / (run.cell.dt_ns * 1e-9)  # [rad/s] per write
    assert (steps <= run.cell.profile.array("velocity") * 1.001).all()
    assert steps[-1].max() < 1e-3  # [rad/s]: at rest at the end


def test_a_second_signal_aborts_the_retreat_and_the_arm_holds():
    before = signal.getsignal(signal.SIGINT)  # not always Python's default: another library (Spark) may own it
    run = Run(parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 3}))
    # the operator presses mid-motion, then again well into the retreat
    setpoints: list = []
    writes = _run_pressing(run, lambda writes: len(writes) == 1500 or (writes[-1] and writes.count(1) == 150),
                           setpoints)
    assert run.stopped == "operator stop (SIGINT)" and len(run.cycles) == 1
    kinds = [e.kind for e in run.events]
    assert kinds.index("operator_stop") < kinds.index("retreat_begin") < kinds.index("retreat_aborted")
    assert "retreat_done" not in kinds
    braking = setpoints[-(writes.count(1) - 150) - 1:]
    assert len(braking) > 10 and np.abs(braking[1] - braking[0]).max() > 1e-4  # it was moving when pressed
    _brakes_and_holds(run, braking)  # then it brakes and holds where it stopped
    assert signal.getsignal(signal.SIGINT) is before  # restored after the run


def test_the_third_signal_raises_keyboard_interrupt_and_the_handlers_are_restored():
    before = {signum: signal.getsignal(signum) for signum in (signal.SIGINT, signal.SIGTERM)}
    with pytest.raises(KeyboardInterrupt):
        with OperatorStop() as operator:
            signal.raise_signal(signal.SIGTERM)
            signal.raise_signal(signal.SIGINT)
            assert (operator.count, operator.signal) == (2, "SIGTERM")
            signal.raise_signal(signal.SIGINT)
    assert {signum: signal.getsignal(signum) for signum in before} == before


def test_a_signal_during_the_last_retreat_aborts_it_and_the_run_is_stopped():
    run = Run(parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 0}))
    run.cell.q_home = run.cell.q_home + np.eye(len(run.cell.q_home))[0] * 0.2  # the cycle ends away from home
    setpoints: list = []
    writes = _run_pressing(run, lambda writes: writes[-1] and writes.count(1) == 5, setpoints)
    assert run.stopped == "operator stop (SIGINT)" and run.cycles.total == 1
    assert [e.kind for e in run.events][-3:] == ["retreat_begin", "operator_stop", "retreat_aborted"]
    _brakes_and_holds(run, setpoints[-(writes.count(1) - 5) - 1:])


def test_a_second_signal_before_the_retreat_begins_still_aborts_it():
    """Two presses in quick succession (the second inside the stop ramp, before the retreat): the retreat went
    all the way home."""
    run = Run(parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 3}))
    writes = _run_pressing(run, lambda writes: len(writes) in (1500, 1520))
    kinds = [e.kind for e in run.events]
    assert kinds[-2:] == ["retreat_begin", "retreat_aborted"] and writes.count(1) == 0


def test_a_signal_during_the_approach_brakes_it_under_the_limits_and_the_stop_follows_it():
    """The approach's setpoints stopped dead at full speed (63 mrad in one tick on the real-time loop), and the
    guard's protective stop was stamped when the approach began, before the signal that caused it."""
    run = Run(parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 1}))
    cell = run.cell
    q = cell.q_home + np.array([0.6, 0.3, -0.4, 0.0, 0.0, 0.0])
    cell.data.qpos[cell.drives.qadr] = q
    cell.write(q)
    mujoco.mj_forward(cell.model, cell.data)
    run.guard = build_guard(cell, run.scenario.guard)  # the guard holds where the robot is until the approach
    setpoints: list = []
    _run_pressing(run, lambda writes: len(writes) == 200, setpoints)
    events = {e.kind: e for e in run.events}
    assert run.stopped == "operator stop (SIGINT)" and "approach_done" not in events
    aborted = events["approach_aborted"]
    assert events["operator_stop"].t_ns == aborted.t_ns <= events["protective_stop"].t_ns
    moving = np.abs(np.diff(np.array(setpoints[:200]), axis=0)).max() / (cell.dt_ns * 1e-9)
    assert moving > 0.3 * cell.profile.array("velocity").min()  # pressed at speed
    steps = np.abs(np.diff(np.array(setpoints), axis=0)) / (cell.dt_ns * 1e-9)
    assert (steps <= cell.profile.array("velocity") * 1.001).all()  # no step anywhere, the stop included


def test_ctrl_c_in_a_release_stage_counts_no_run_and_evaluates_no_gate(tmp_path, monkeypatch):
    plan, site, release = two_runs_at_sim(tmp_path, 3)
    cycle = Run.cycle

    def press_at_the_second_cycle(run):
        if run.cycles.total == 1:
            signal.raise_signal(signal.SIGINT)
        return cycle(run)

    monkeypatch.setattr(Run, "cycle", press_at_the_second_cycle)
    result = cli("run", "--cell", CELL, "--stage", "sim", "--plan", str(plan), "--site", str(site))
    assert result.exit_code == 130, result.output
    line = result.stderr.strip().splitlines()[-1]
    assert line.startswith("stopped by the operator: operator stop (SIGINT) during sim run 'first'")
    assert "gates were not evaluated" in line
    folders = list((site / "runs" / CELL / "sim").iterdir())
    assert len(folders) == 1  # the second run never started
    assert json.loads((folders[0] / "summary.json").read_text())["stopped"] == "operator stop (SIGINT)"
    assert Store(site).runs(CELL, "sim", release) == []  # not evidence
    assert [e.body["kind"] for e in entries(Store(site))] == ["promote"]  # no gates entry
    # the stage runs again: the stopped run's folder is kept and the new runs are numbered past it
    monkeypatch.undo()
    result = cli("run", "--cell", CELL, "--stage", "sim", "--plan", str(plan), "--site", str(site))
    assert result.exit_code == 0, result.output
    assert sorted(f.name for f in (site / "runs" / CELL / "sim").iterdir()) == ["0001-first", "0002-first",
                                                                                "0003-second"]
    assert [r.name for r in Store(site).runs(CELL, "sim", release)] == ["first", "second"]


def _stage_signalled_at_close(tmp_path, monkeypatch, stopped: str | None = None):
    """Two sim runs of a release stage; SIGINT raised while the first run closes (its record, then its summary),
    after it stopped for ``stopped`` if given: (the command's result, the site, the release, the run folders)."""
    plan, site, release = two_runs_at_sim(tmp_path, 1)
    close = Run.close

    def close_under_a_signal(run):
        run.stopped = run.stopped or stopped
        signal.raise_signal(signal.SIGINT)
        close(run)

    monkeypatch.setattr(Run, "close", close_under_a_signal)
    result = cli("run", "--cell", CELL, "--stage", "sim", "--plan", str(plan), "--site", str(site))
    return result, site, release, list((site / "runs" / CELL / "sim").iterdir())


def test_ctrl_c_while_a_release_runs_record_closes_stops_the_stage(tmp_path, monkeypatch):
    """A signal after the cycles, while the record closed or the summary was written, was counted and forgotten:
    the stage started its next run, evaluated its gates and exited 0 (the operator's stop ignored)."""
    result, site, release, folders = _stage_signalled_at_close(tmp_path, monkeypatch)
    assert result.exit_code == 130, result.output
    assert "during sim run 'first'" in result.stderr.strip().splitlines()[-1]
    assert len(folders) == 1  # the second run never started
    assert json.loads((folders[0] / "summary.json").read_text())["stopped"] == "operator stop (SIGINT)"
    assert Store(site).runs(CELL, "sim", release) == []
    assert [e.body["kind"] for e in entries(Store(site))] == ["promote"]


def test_ctrl_c_after_a_run_stopped_for_another_reason_still_stops_the_stage(tmp_path, monkeypatch):
    """After a fault stop is when an operator presses Ctrl-C: the signal was forgotten and the stage ran its next
    run. The run stays the fault's evidence (counted, its reason kept); the stage stops there."""
    result, site, release, folders = _stage_signalled_at_close(tmp_path, monkeypatch,
                                                               "robot link: the server vanished")
    assert result.exit_code == 130, result.output
    assert "after it stopped (robot link: the server vanished)" in result.stderr.strip().splitlines()[-1]
    assert len(folders) == 1  # the second run never started
    assert json.loads((folders[0] / "summary.json").read_text())["stopped"] == "robot link: the server vanished"
    assert [r.name for r in Store(site).runs(CELL, "sim", release)] == ["first"]  # a fault's run is evidence
    assert [e.body["kind"] for e in entries(Store(site))] == ["promote"]  # no gates entry


def test_a_stop_during_an_operator_hand_over_hold_plays_no_retreat():
    """Ctrl-C while the cell was held for an operator (someone in the cell): the attempt read 'resumed' and the
    arm was driven home at once."""
    recovery = {"behaviours": [{"do": "retry_grasp", "trigger": "grasp_missed", "then": "operator"},
                               {"do": "operator", "hold_s": 20.0}]}
    run = Run(parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 0, "production_cycles": 2, "seed": 7,
                              "faults": [{"kind": "fixture_shift", "at_cycle": 0, "dx_mm": 15.0}],
                              "recovery": recovery}))
    setpoints: list = []
    held = lambda: run.recovery.stop is not None  # noqa: E731
    _run_pressing(run, lambda writes: held() and not run.events.has("operator_stop"), setpoints)
    kinds = [e.kind for e in run.events]
    assert run.stopped == "operator stop (SIGINT)" and "retreat_begin" not in kinds
    assert "operator_stop" in kinds  # the signal came while the arm was already held still: it was not logged
    assert kinds[-1] == "retreat_aborted" and "hand-over hold" in run.events[-1].reason
    assert run.cycles[-1]["recovery_log"][-1]["outcome"] == "cut_off"
    _brakes_and_holds(run, setpoints[-200:])  # the hold's stop, then still
    assert np.abs(setpoints[-1][:-1] - run.cell.q_home[:-1]).max() > 0.05  # not driven home


def test_a_stop_during_a_recovery_attempt_cuts_it_off():
    """Ctrl-C mid retry_grasp read 'resumed': fixes.json and the advice would count an aborted attempt as a fix."""
    recovery = {"behaviours": [{"do": "retry_grasp", "trigger": "grasp_missed", "attempts": 2}]}
    run = Run(parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 0, "production_cycles": 2, "seed": 7,
                              "faults": [{"kind": "fixture_shift", "at_cycle": 0, "dx_mm": 15.0}],
                              "recovery": recovery}))
    _run_pressing(run, lambda writes: run.recovery.attempting and not run.events.has("operator_stop"))
    assert run.stopped == "operator stop (SIGINT)"
    assert run.cycles[-1]["recovery_log"][-1]["outcome"] == "cut_off"


def test_signals_while_the_record_closes_are_counted_and_the_summary_is_written(tmp_path):
    """Two quick signals after the cycles met Python's own handlers: exit 130 (SIGTERM: killed) and no summary.
    In a child process: without the handlers the signal ends whoever receives it."""
    script = (
        "import signal, sys\n"
        "from cellguard.runtime import Run, run_scenario\n"
        "from cellguard.scenario import parse_scenario\n"
        "scenario = parse_scenario({'cell': 'arm-pick-place', 'acceptance_cycles': 1, 'production_cycles': 0})\n"
        "run = Run(scenario)\n"
        "close = run.close\n"
        "def close_under_signals():\n"
        "    signal.raise_signal(signal.SIGTERM)\n"
        "    signal.raise_signal(signal.SIGINT)\n"
        "    close()\n"
        "run.close = close_under_signals\n"
        "run_scenario(scenario, sys.argv[1], run=run)\n"
        "print(run.operator.count)\n")
    done = subprocess.run([sys.executable, "-c", script, str(tmp_path / "out")], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "2", (done.returncode, done.stderr[-500:])
    assert (tmp_path / "out" / "summary.json").is_file()
