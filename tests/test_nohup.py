"""A signal ignored when cellguard starts stays ignored: ``nohup cellguard run ...`` (SIGHUP set to SIG_IGN by the
parent) was still stopped by a closed terminal's SIGHUP (exit 130, the run cut short), as cellguard put its own
handlers in place of the inherited SIG_IGN. Without the ignore, SIGHUP stops the run as before."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest
import yaml

from cellguard.ending import ended_by_signals
from cellguard.runtime.operator_stop import OperatorStop

CYCLES = {"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 8}


def _hangup_mid_run(tmp_path, ignored: bool) -> tuple[subprocess.Popen, str]:
    """``cellguard run`` in a session of its own (SIGHUP ignored by its parent, as nohup does, if ``ignored``), sent
    SIGHUP to its whole group once its record is being written, as a closed terminal does; the process, its stderr."""
    scenario = tmp_path / "scenario.yaml"
    scenario.write_text(yaml.safe_dump(CYCLES))
    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-c", "from cellguard.cli import app; app()", "run", str(scenario),
                             "--out", str(out), "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True,
                            preexec_fn=(lambda: signal.signal(signal.SIGHUP, signal.SIG_IGN)) if ignored else None)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not ((out / "record.mcap").exists()
                                               and (out / "record.mcap").stat().st_size > 100_000):
        time.sleep(0.02)  # the ticks are being written: the loop runs
    assert proc.poll() is None, proc.communicate()  # the signal comes mid-run
    os.killpg(proc.pid, signal.SIGHUP)
    _, stderr = proc.communicate(timeout=300)
    return proc, stderr


def test_a_run_started_with_sighup_ignored_runs_to_its_end_through_a_hangup(tmp_path):
    proc, stderr = _hangup_mid_run(tmp_path, ignored=True)
    assert proc.returncode == 0, stderr
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert "stopped" not in summary and len(summary["cycles"]) == 9
    assert "operator_stop" not in [e["kind"] for e in summary["events"]]


def test_without_the_ignore_a_hangup_still_stops_the_run(tmp_path):
    proc, stderr = _hangup_mid_run(tmp_path, ignored=False)
    assert proc.returncode == 130, stderr
    assert stderr.splitlines()[-1].startswith("stopped by the operator: operator stop (SIGHUP)")
    assert json.loads((tmp_path / "run" / "summary.json").read_text())["stopped"] == "operator stop (SIGHUP)"


@pytest.mark.parametrize("block", [ended_by_signals, OperatorStop])
def test_an_ignored_signal_stays_ignored_inside_each_handler_block_and_the_others_are_handled(block):
    before = {signum: signal.getsignal(signum) for signum in (signal.SIGHUP, signal.SIGTERM)}
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        with block():
            assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
            assert callable(signal.getsignal(signal.SIGTERM))  # not ignored: taken over as before
        assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
        assert signal.getsignal(signal.SIGTERM) is before[signal.SIGTERM]
    finally:
        for signum, handler in before.items():
            signal.signal(signum, handler)
