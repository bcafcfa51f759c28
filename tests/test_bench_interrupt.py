"""Ctrl-C during `cellguard bench`'s record group ends it in one line, exit 130: its recordings are not closed
on the way out, and at exit Python joined the recorder's writer process, which ignores SIGINT and SIGTERM and waited
for the end of its pipe: the bench hung until someone killed the writer."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest


def _children(pid: int) -> list[str]:
    return subprocess.run(["pgrep", "-P", str(pid)], capture_output=True, text=True).stdout.split()


def test_ctrl_c_in_the_record_group_ends_the_bench_in_one_line(tmp_path):
    bench = subprocess.Popen([sys.executable, "-c", "from cellguard.entry import main; main()", "bench", "--only",
                              "record", "--quick"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                             cwd=tmp_path)
    deadline = time.monotonic() + 120
    while not _children(bench.pid) and bench.poll() is None and time.monotonic() < deadline:
        time.sleep(0.1)  # until a recording is open: its writer is the bench's child process
    time.sleep(0.5)
    assert bench.poll() is None and _children(bench.pid), "no recording open before the signal: nothing tested"
    bench.send_signal(signal.SIGINT)
    try:
        out, err = bench.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        for child in _children(bench.pid):
            subprocess.run(["kill", "-KILL", child])
        bench.communicate(timeout=30)
        pytest.fail("bench did not end within 60 s of SIGINT (the recorder's writer held it)")
    assert bench.returncode == 130 and out == ""
    assert "error: benchmark record: stopped by the operator (SIGINT); no figures\n" in err
