"""The record benchmark's attribution of a slow recorder call: its own work, or time off the CPU."""

from __future__ import annotations

import time

from cellguard.bench.record import _SlowCalls


def _timed(slow: _SlowCalls, work) -> None:
    began = slow.before()
    t = time.perf_counter_ns()
    work()
    slow.after(began, time.perf_counter_ns() - t)


def _spin(cpu_ns: int) -> None:
    end = time.thread_time_ns() + cpu_ns
    while time.thread_time_ns() < end:
        pass


def test_a_call_busy_past_the_limit_is_the_recorders_own_work():
    slow = _SlowCalls(limit_ns=200_000)
    _timed(slow, lambda: _spin(400_000))
    assert slow.counts["on_cpu"] == 1 and sum(slow.counts.values()) == 1


def test_a_call_that_blocks_is_time_off_the_cpu_not_work():
    slow = _SlowCalls(limit_ns=200_000)
    _timed(slow, lambda: time.sleep(0.005))  # a voluntary switch, as a wait for the GIL is
    assert slow.counts["on_cpu"] == 0 and slow.counts["waited"] + slow.counts["preempted"] == 1


def test_a_fast_call_is_not_counted():
    slow = _SlowCalls(limit_ns=200_000)
    _timed(slow, lambda: None)
    assert sum(slow.counts.values()) == 0
