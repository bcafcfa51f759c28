"""A thread or process cellguard starts on a run's path that the OS refuses (its thread or process limit, memory) is a
refusal to start, one line, never a traceback: the policy's inference worker (its thread, or its process: EAGAIN from
the spawn was a BlockingIOError traceback, exit 1) a start-up refusal in the record (as a policy its process could not
build), exit 2; a LeRobot bridge's call thread a bridge error before the robot is connected."""

from __future__ import annotations

import errno
import multiprocessing
import multiprocessing.util
import re
import subprocess
import sys
import threading

import numpy as np
import pytest

from cellguard.errors import CellguardError
from cellguard.policy.chunk import ActionChunk
from cellguard.record.reader import open_record
from cellguard.robot.bridges.lerobot import RobotCalls
from cellguard.runtime import Run
from cellguard.runtime.startup import StartupRefused
from cellguard.scenario import parse_scenario

MS = 1_000_000
REFUSED = "can't start new thread"
THREAD = rf"its thread 'cellguard-inference' could not start \({REFUSED}\)"
PROCESS = r"its process 'cellguard-policy' could not start \(\[Errno 11\] Resource temporarily unavailable\)"
# the OS refusing one named thread (as the interpreter says it), or the policy's spawned process (EAGAIN: the
# recorder's writer is forked, not spawned), then the CLI
CLI = f"""
import errno, multiprocessing.util, sys, threading
start = threading.Thread.start
def refused(self):
    if self.name == sys.argv[1]:
        raise RuntimeError({REFUSED!r})
    return start(self)
def no_process(*args):
    raise BlockingIOError(errno.EAGAIN, "Resource temporarily unavailable")
threading.Thread.start = refused
if sys.argv[1] == "cellguard-policy":
    multiprocessing.util.spawnv_passfds = no_process
from cellguard.cli import app
app(sys.argv[2:], prog_name="cellguard")
"""


class _Still:
    """Holds the pose it is shown, in 25 steps of 20 ms."""

    source = "test:still"

    def reset(self):
        pass

    def content_hash(self):
        return "0" * 64

    def infer(self, observation):
        return ActionChunk(np.tile(observation.q, (25, 1)), observation.t_ns, 20 * MS)


@pytest.fixture
def no_thread(monkeypatch):
    """Thread.start refused, as the OS refuses it, for threads of the given name."""
    names: set[str] = set()
    start = threading.Thread.start

    def refused(self):
        if self.name in names:
            raise RuntimeError(REFUSED)
        return start(self)

    monkeypatch.setattr(threading.Thread, "start", refused)
    return names


def _no_process(*args):
    """The spawn of a process refused, as the OS refuses a fork at its process limit."""
    raise BlockingIOError(errno.EAGAIN, "Resource temporarily unavailable")


@pytest.mark.parametrize("worker, refused", [("thread", THREAD), ("process", THREAD), ("process", PROCESS)],
                         ids=["thread", "process-thread", "process"])
def test_an_inference_worker_the_os_refuses_is_a_start_up_refusal_before_the_robot_moves(no_thread, monkeypatch,
                                                                                         worker, refused):
    if refused == THREAD:
        no_thread.add("cellguard-inference")
    else:
        monkeypatch.setattr(multiprocessing.util, "spawnv_passfds", _no_process)
    scenario = parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 0,
                               "cycle": {"source": "time", "seconds": 1.0}, "realtime": {"inference": worker}})
    run = Run(scenario, realtime=True, policy_factory=_Still)
    q0 = run.cell.read().q
    try:
        with pytest.raises(StartupRefused, match=rf"^start-up: the policy's inference worker: {refused}; not moving$"):
            run.cycle()
    finally:
        run.close()  # no thread to join: returns
    assert [e.kind for e in run.events][-1] == "startup_refused"
    assert np.abs(run.cell.read().q - q0).max() < 1e-3
    for child in multiprocessing.active_children():  # a process worker's policy process: killed with it
        child.join(5.0)
        assert not child.is_alive(), child


@pytest.mark.parametrize("name, refused", [("cellguard-inference", THREAD), ("cellguard-policy", PROCESS)],
                         ids=["thread", "process"])
def test_the_cli_says_so_in_one_line_exit_2_and_the_record_says_why(tmp_path, name, refused):
    worker = "process" if name == "cellguard-policy" else "thread"
    (tmp_path / "sc.yaml").write_text(f"cell: arm-pick-place\nacceptance_cycles: 1\nproduction_cycles: 0\n"
                                      f"realtime: {{inference: {worker}}}\n")
    done = subprocess.run([sys.executable, "-c", CLI, name, "run", "sc.yaml", "--out", "out", "--realtime"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 2, done.stderr
    assert re.match(rf"error: start-up: the policy's inference worker: {refused}; not moving", done.stderr), \
        done.stderr
    assert done.stderr.count("\n") == 1, done.stderr
    with open_record(tmp_path / "out") as rec:
        assert [e.kind for e in rec.events()] == ["startup_refused"]


def test_a_lerobot_call_thread_the_os_refuses_is_one_bridge_error(no_thread):
    no_thread.add("lerobot arm")
    with pytest.raises(CellguardError) as refused:
        RobotCalls("arm", timeout_s=0.05)
    assert str(refused.value) == (f"lerobot arm: cannot drive the robot: its thread 'lerobot arm' could not start "
                                  f"({REFUSED}); not connected")
