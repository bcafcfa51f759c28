"""benchmarks/fleet_runs.py killed with SIGKILL (no handler runs, no pool is shut down) takes its pool workers with
it: they made their runs for minutes, orphaned, then waited on their queue for good (Linux)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def _descendants(pid: int) -> list[int]:
    listed = subprocess.run(["pgrep", "-P", str(pid)], capture_output=True, text=True).stdout
    children = [int(c) for c in listed.split()]
    return children + [d for c in children for d in _descendants(c)]


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the death signal is Linux's (prctl)")
def test_sigkill_of_fleet_runs_ends_its_workers(tmp_path):
    runs = tmp_path / "runs"
    proc = subprocess.Popen([sys.executable, str(BENCH / "fleet_runs.py"), str(runs)], cwd=tmp_path,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        while not list(runs.glob("*.partial")) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)  # a worker is inside a run
        assert proc.poll() is None and list(runs.glob("*.partial")), "no run started: nothing tested"
        workers = _descendants(proc.pid)
        assert workers
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        deadline = time.monotonic() + 5
        while any(map(_alive, workers)) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert [w for w in workers if _alive(w)] == []
    finally:  # whatever is left of its session
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
