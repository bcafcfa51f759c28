"""benchmarks/realtime.py reads its sim-server's output to the end. Read only up to the start line, the pipe filled
(64 KiB: about three minutes of the server's once-a-second notes of stray packets) and the server blocked mid-tick
on its next note: its robot stalled, and the run's stop was read as the loop's. Here the pipe is filled at once, as
a long run leaves it, and one stray packet makes the server write its note. A server that ends during a run is
reported in its own last line."""

from __future__ import annotations

import errno
import importlib.util
import os
import re
import signal
import socket
import threading
import time
from pathlib import Path

from sim_server_util import server_counters

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def _realtime():
    spec = importlib.util.spec_from_file_location("bench_realtime", BENCH / "realtime.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _child_server(deadline: float) -> tuple[int, int] | None:
    """(pid, port) of this process's sim-server child once it runs."""
    while time.monotonic() < deadline:
        for entry in Path("/proc").iterdir():
            try:
                if not entry.name.isdigit() or int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1]) \
                        != os.getpid():
                    continue
                args = (entry / "cmdline").read_bytes().decode().split("\0")
            except (OSError, IndexError, ValueError):
                continue
            if "sim-server" in args:
                return int(entry.name), int(args[args.index("--port") + 1])
        time.sleep(0.05)
    return None


def _fill(pid: int, within_s: float = 1.0) -> int:
    """Fill the pipe the server writes its output to, as a long run's notes left it; the bytes written. The run's
    reader drains it meanwhile: the filling stops after ``within_s`` where it never stays full (on a busy host
    it wrote 133 MB, the 5 s run ended meanwhile and the server's counters could not be read)."""
    fd = os.open(f"/proc/{pid}/fd/1", os.O_WRONLY | os.O_NONBLOCK)
    written, until = 0, time.monotonic() + within_s
    try:
        while time.monotonic() < until:
            try:
                written += os.write(fd, b"sim-server: an earlier note of a long run\n")
            except OSError as exc:
                if exc.errno != errno.EAGAIN:
                    raise
                break
    finally:
        os.close(fd)
    return written


def _run_meddled(tmp_path, meddle) -> dict:
    """A 5 s run of benchmarks/realtime.py (200 Hz, no record) with ``meddle(pid, port)`` called on a thread once
    the run's client has said hello to its sim-server."""

    def once_served() -> None:
        found = _child_server(time.monotonic() + 60)
        if found is None:
            return
        pid, port = found
        deadline = time.monotonic() + 60
        while server_counters(port).get("sessions", 0) < 1 and time.monotonic() < deadline:
            time.sleep(0.1)  # the run's client said hello: the start line was read
        meddle(pid, port)

    meddler = threading.Thread(target=once_served, daemon=True)
    meddler.start()
    run = _realtime().one_run(200.0, "sway", "thread", 5.0, tmp_path / "unused.onnx", 0, tmp_path / "run",
                              recording=False)
    meddler.join(10)
    return run


def test_a_server_whose_output_pipe_fills_keeps_serving(tmp_path):
    seen: dict = {}

    def meddle(pid: int, port: int) -> None:
        seen["filled"] = _fill(pid)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as stray:
            stray.sendto(b"X", ("127.0.0.1", port))  # a packet of no kind: the server writes a note
        time.sleep(1.0)
        seen["answers"] = server_counters(port)

    run = _run_meddled(tmp_path, meddle)
    assert seen.get("filled", 0) > 4096, seen  # the pipe was full: nothing tested otherwise
    assert seen["answers"].get("malformed_packets") == 1, (seen, run)  # still serving after its note
    assert run.get("stopped") is None and "refused" not in run and "server_ended" not in run, run
    assert not {"robot_read_timeout", "protective_stop"} & set(run["events"]), run  # the stall read as the loop's


def test_a_server_that_ends_during_a_run_is_reported_in_its_own_words(tmp_path):
    run = _run_meddled(tmp_path, lambda pid, port: os.kill(pid, signal.SIGKILL))
    # its last words: the note of the run's client saying hello
    assert re.fullmatch(r"sim-server ended \(exit code -9\): sim-server: client 127\.0\.0\.1:\d+ said hello",
                        run.get("server_ended", "")), run
