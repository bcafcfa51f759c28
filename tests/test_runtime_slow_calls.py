"""Why a recorder call on the servo thread was slow: on the CPU, or off it (waited, preempted); the loop's
summary says it on wall time."""

from __future__ import annotations

import time

from cellguard.runtime.timing import SlowCalls, TickTiming


def _timed(slow: SlowCalls, work) -> None:
    began = slow.before()
    t = time.perf_counter_ns()
    work()
    slow.after(began, time.perf_counter_ns() - t)


def _spin(cpu_ns: int) -> None:
    end = time.thread_time_ns() + cpu_ns
    while time.thread_time_ns() < end:
        pass


def test_a_call_busy_past_the_limit_ran_on_the_cpu():
    slow = SlowCalls(limit_ns=200_000)
    _timed(slow, lambda: _spin(400_000))
    assert slow.counts["on_cpu"] == 1 and sum(slow.counts.values()) == 1


def test_a_call_that_blocks_is_time_off_the_cpu_not_work():
    slow = SlowCalls(limit_ns=200_000)
    _timed(slow, lambda: time.sleep(0.005))  # a voluntary switch, as a wait for the GIL is
    assert slow.counts["on_cpu"] == 0 and slow.counts["waited"] + slow.counts["preempted"] == 1


def test_a_fast_call_is_not_counted():
    slow = SlowCalls(limit_ns=200_000)
    _timed(slow, lambda: None)
    assert sum(slow.counts.values()) == 0


def test_the_tick_timing_says_why_on_wall_time_and_not_in_simulated_time():
    wall, simulated = TickTiming(1_000_000, explain_slow=True), TickTiming(1_000_000)
    for timing, began in ((wall, wall.recorder_slow.before), (simulated, lambda: None)):
        timing.add(0, 0)
        for work in (lambda: time.sleep(0.002), lambda: _spin(400_000), lambda: None):
            usage, t = began(), time.perf_counter_ns()
            work()
            timing.recorder(time.perf_counter_ns() - t, usage)
    cost = wall.summary()["recorder_tick_us"]
    assert cost["over_200us"] == 2 and cost["max"] >= 2000.0
    assert cost["over_200us_why"]["on_cpu"] == 1 and sum(cost["over_200us_why"].values()) == 2
    assert simulated.summary()["recorder_tick_us"]["over_200us"] == 2
    assert "over_200us_why" not in simulated.summary()["recorder_tick_us"]  # nothing was read: no reason given
