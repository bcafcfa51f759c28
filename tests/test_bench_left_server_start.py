"""benchmarks/realtime.py and the sim-server tests wait for the server's start line a bounded time. Waited on for
ever, a server that hung before printing it (measured: a sim-server stopped at its start) hung the benchmark or the
test for good. Here the server is a command that never prints one: the wait ends in one error naming the command,
and the process is killed."""

from __future__ import annotations

import importlib.util
import os
import shlex
import sys
import threading
import time
from pathlib import Path

import pytest
import sim_server_util

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "realtime.py"


def _silent(tmp_path) -> list[str]:
    """A command that never prints a start line; it writes its pid to ``tmp_path/pid`` first."""
    return [sys.executable, "-c", f"import os, time; open({str(tmp_path / 'pid')!r}, 'w').write(str(os.getpid())); "
                                  f"time.sleep(600)"]


def _bounded(call, seconds: float = 60.0):
    """``call()``'s result or exception; the test fails if it is still waiting after ``seconds``."""
    out: list = []

    def run() -> None:
        try:
            out.append(call())
        except Exception as exc:  # noqa: BLE001 - handed to the test
            out.append(exc)

    waiter = threading.Thread(target=run, daemon=True)
    waiter.start()
    waiter.join(seconds)
    if not out:
        pytest.fail(f"still waiting for the start line after {seconds} s")
    return out[0]


def _gone(tmp_path) -> bool:
    try:
        os.kill(int((tmp_path / "pid").read_text()), 0)
    except ProcessLookupError:
        return True
    return False


def test_start_server_gives_up_on_a_server_that_never_says_it_listens(tmp_path):
    command = _silent(tmp_path)
    began = time.monotonic()
    error = _bounded(lambda: sim_server_util.started(command, timeout_s=1.0))
    assert isinstance(error, RuntimeError), error
    assert str(error) == f"sim-server did not start ({shlex.join(command)}): printed no start line within 1 s"
    assert time.monotonic() - began < 30 and _gone(tmp_path)


def test_the_benchmark_gives_up_on_a_server_that_never_says_it_serves(tmp_path):
    spec = importlib.util.spec_from_file_location("bench_realtime", BENCH)
    realtime = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(realtime)
    command = _silent(tmp_path)
    server = realtime.SimServerProcess(command)
    try:
        said = _bounded(lambda: server.serving(within_s=1.0))
    finally:
        server.stop()
    assert said == f"sim-server did not say it serves within 1 s, killed: {shlex.join(command)}"
    assert _gone(tmp_path)



def test_a_server_refusing_its_port_is_not_taken_for_started():
    """The sim-server's refusal names the address too ("cannot listen on udp://127.0.0.1:PORT"): read as its start
    line, a server that had already ended was handed to the test as serving."""
    refusal = "error: --port: cannot listen on udp://127.0.0.1:5 (Address already in use)"
    command = [sys.executable, "-c", f"import sys; print({refusal!r}); sys.exit(2)"]
    error = _bounded(lambda: sim_server_util.started(command, timeout_s=30.0))
    assert isinstance(error, RuntimeError), error
    assert f"said {refusal + chr(10)!r} (" in str(error)  # exit code 2, or killed as it ended
