"""Helpers for the sim-server tests: a real server process on a free loopback port, a replay policy file."""

from __future__ import annotations

import contextlib
import json
import os
import shlex
import socket
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np

HOME = np.array([0.0, -0.3, 1.9, 1.55, 0.0, 0.025])  # the arm cell's home pose


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# [s] for the start line: 1.1 s measured on a quiet 2-core host, up to 24 s with six busy processes beside it
START_S = 60.0


def start_server(*args: str, cell: str = "arm-pick-place", timeout_s: float = START_S) -> tuple[subprocess.Popen, int]:
    """``cellguard sim-server`` in its own process; returns once it listens."""
    port = free_port()
    command = [sys.executable, "-c", "from cellguard.cli import app; app()", "sim-server", cell, "--port", str(port),
               *args]
    return started(command, timeout_s), port


@contextlib.contextmanager
def served(*args: str, cell: str = "arm-pick-place"):
    """``start_server`` for a block: its port, the server killed after."""
    proc, port = start_server(*args, cell=cell)
    try:
        yield port
    finally:
        proc.kill()
        proc.wait()


def started(command: list[str], timeout_s: float = START_S) -> subprocess.Popen:
    """``command`` in its own process, once it has printed its start line (``sim-server CELL on udp://127.0.0.1:...``;
    its refusal names that address too); RuntimeError naming it, the process killed, if it ends first, prints
    another line or prints none within ``timeout_s`` (waited on for ever, a server that hung before its start line
    hung the test)."""
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    said: list[str] = []
    reader = threading.Thread(target=lambda: said.append(proc.stdout.readline()), daemon=True)
    reader.start()
    reader.join(timeout_s)
    line = said[0] if said else None  # None: nothing yet
    if line is not None and line.startswith("sim-server ") and "udp://127.0.0.1" in line:
        return proc
    proc.kill()  # its pipe then ends, and so does the reader
    reader.join()
    said = None if line is None else line + proc.stdout.read()
    code = proc.wait()
    why = (f"printed no start line within {timeout_s:g} s" if said is None
           else f"said {said!r} ({'killed' if code < 0 else f'exit code {code}'})")
    raise RuntimeError(f"sim-server did not start ({shlex.join(command)}): {why}")


def server_counters(port: int) -> dict:
    """The server's counters, asked as any local peer may (``?``); empty if it does not answer in 0.5 s."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.settimeout(0.5)
        s.sendto(b"?", ("127.0.0.1", port))
        try:
            return json.loads(s.recv(65536)[1:])
        except TimeoutError:
            return {}


def sway_file(path: Path, seconds: float = 30.0, nan_at_s: float | None = None) -> Path:
    """Replay chunks (every 50 ms, 25 steps of 20 ms) that sway the shoulder around the home pose."""
    t = np.arange(0.0, seconds, 0.05)
    steps = t[:, None] + np.arange(25)[None, :] * 0.02
    actions = np.broadcast_to(HOME, (len(t), 25, 6)).copy()
    actions[:, :, 0] = 0.1 * np.sin(2 * np.pi * 0.5 * steps)
    if nan_at_s is not None:
        actions[int(nan_at_s / 0.05):, :, 1] = np.nan
    np.savez(path, t=t, actions=actions, dt=0.02)
    return path


# Wide link limits: eight processes share two cores here, so ticks wake milliseconds late;
# each test narrows the one limit it is about.
LOADED = {"stale_s": 0.25, "read_timeout_s": 0.1, "overrun_budget": 1_000_000}


def scenario(port: int, policy: Path, **realtime) -> dict:
    realtime = {**LOADED, **realtime}
    return {"cell": "arm-pick-place", "robot": f"sim-server:udp://127.0.0.1:{port}", "policy": f"replay:{policy}",
            "acceptance_cycles": 1, "production_cycles": 0, "cycle": {"source": "time", "seconds": 2.0},
            "realtime": realtime}
