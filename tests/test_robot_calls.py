"""A bridge's robot calls on a thread of their own: a hung bus is a timeout the loop sees, never a frozen tick."""

from __future__ import annotations

import subprocess
import sys
import threading
import time

import pytest

from cellguard.robot.bridges.lerobot import RobotCalls


def test_a_call_returns_its_result_and_raises_its_own_error():
    calls = RobotCalls("arm", timeout_s=1.0)
    assert calls("get_observation", lambda a, b: a + b, 2, 3) == 5
    with pytest.raises(KeyError, match="shoulder_pan"):
        calls("get_observation", lambda: {}["shoulder_pan"])
    assert calls.hung_for_ns() == 0


def test_a_hung_call_times_out_and_the_next_fails_at_once_until_it_returns():
    calls, bus = RobotCalls("arm", timeout_s=0.05), threading.Event()
    t0 = time.monotonic()
    with pytest.raises(TimeoutError, match=r"lerobot arm: get_observation has not returned for \d+ ms \(limit 50 ms\)"):
        calls("get_observation", bus.wait)
    assert 0.04 < time.monotonic() - t0 < 1.0
    sent = []
    t0 = time.monotonic()
    with pytest.raises(TimeoutError, match="get_observation has not returned"):  # not queued behind the read
        calls("send_action", sent.append, {"gripper.pos": 50.0})
    assert time.monotonic() - t0 < 0.03 and sent == [] and calls.hung_for_ns() > 0
    bus.set()
    deadline = time.monotonic() + 5.0
    while calls.hung_for_ns() and time.monotonic() < deadline:
        time.sleep(0.001)
    assert calls("send_action", sent.append, {"gripper.pos": 50.0}) is None and sent == [{"gripper.pos": 50.0}]


def test_a_call_hung_forever_does_not_keep_the_process_alive():
    code = ("from cellguard.robot.bridges.lerobot import RobotCalls\n"
            "import threading\n"
            "calls = RobotCalls('arm', timeout_s=0.05)\n"
            "try:\n"
            "    calls('get_observation', threading.Event().wait)\n"
            "except TimeoutError as exc:\n"
            "    print(exc)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert "get_observation has not returned" in done.stdout
