"""Ctrl-C (SIGINT) or SIGTERM while the cycles run: a category 2 stop, the retreat, a complete record; exit 130."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import yaml

from cellguard.record.reader import open_record
from cellguard.runtime import Run
from cellguard.runtime.operator_stop import OperatorStop
from cellguard.scenario import parse_scenario


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_stop_signal_mid_run_stops_the_arm_retreats_it_and_the_record_says_so(tmp_path, signum):
    scenario = tmp_path / "scenario.yaml"
    scenario.write_text(yaml.safe_dump({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 30}))
    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-c", "from cellguard.cli import app; app()", "run", str(scenario),
                             "--out", str(out), "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not ((out / "record.mcap").exists()
                                               and (out / "record.mcap").stat().st_size > 100_000):
        time.sleep(0.02)  # the ticks are being written: the loop runs
    proc.send_signal(signum)
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    name = signal.Signals(signum).name
    assert stderr.strip().splitlines()[-1].startswith(f"stopped by the operator: operator stop ({name})")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["stopped"] == f"operator stop ({name})"
    assert len(summary["cycles"]) < 31  # the run ended early
    kinds = [e["kind"] for e in summary["events"]]
    assert kinds[:1] == ["operator_stop"] and summary["events"][0]["category"] == 2
    assert kinds[-2:] == ["retreat_begin", "retreat_done"]
    with open_record(out, strict=True) as rec:
        assert rec.health().finished
        events = {e.kind: e for e in rec.events()}
        assert set(kinds) <= set(events)
        held = rec.ticks(start_ns=events["operator_stop"].t_ns, end_ns=events["retreat_begin"].t_ns)
    assert len(held) > 0 and np.abs(held.qd_meas[-1]).max() < 0.05  # at standstill before the retreat


def test_a_second_signal_aborts_the_retreat_and_the_arm_holds():
    before = signal.getsignal(signal.SIGINT)  # not always Python's default: another library (Spark) may own it
    run = Run(parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 3}))
    write, writes = run.cell.write, []

    def write_and_press(setpoint):  # the operator presses mid-motion, then again a few ticks into the retreat
        writes.append(sum(e.kind == "retreat_begin" for e in run.events))
        if len(writes) == 1500 or (writes[-1] and writes.count(1) == 5):
            signal.raise_signal(signal.SIGINT)
        return write(setpoint)

    run.cell.write = write_and_press
    try:
        run.run_cycles()
    finally:
        run.close()
    assert run.stopped == "operator stop (SIGINT)" and len(run.cycles) == 1
    kinds = [e.kind for e in run.events]
    assert kinds.index("operator_stop") < kinds.index("retreat_begin") < kinds.index("retreat_aborted")
    assert "retreat_done" not in kinds
    assert writes.count(1) == 5  # no setpoint after the abort: the arm holds where it is
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
