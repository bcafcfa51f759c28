"""The servo thread while ticking: real-time where permitted, collector paused, all undone after;
the inference worker's per-tick "observation due?" answer equals its definition."""

from __future__ import annotations

import gc
import os
import threading
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cellguard.policy.async_inference import AsyncInference
from cellguard.policy.chunk import ActionChunk
from cellguard.robot.state import Observation
from cellguard.runtime.clock import WallClock
from cellguard.runtime.servo_thread import ServoThread


def _fifo_permitted() -> bool:
    try:
        before = (os.sched_getscheduler(0), os.sched_getparam(0))
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
        os.sched_setscheduler(0, *before)
        return True
    except (AttributeError, OSError):
        return False


def test_ticking_pauses_the_collector_and_restores_everything_after():
    policy_before = os.sched_getscheduler(0)
    helper = threading.Thread(target=time.sleep, args=(0.5,))
    helper.start()
    helper_before = os.sched_getscheduler(helper.native_id)
    assert gc.isenabled()
    with ServoThread() as servo:
        assert not gc.isenabled()
        assert gc.get_freeze_count() > 0  # what existed before the ticks is out of the collector's way
        if _fifo_permitted():
            assert servo.scheduler.startswith("fifo")
            assert os.sched_getscheduler(0) & ~getattr(os, "SCHED_RESET_ON_FORK", 0) == os.SCHED_FIFO
            # the helper thread sits one priority below, so it never holds the GIL preempted by ordinary work
            assert os.sched_getparam(helper.native_id).sched_priority == servo.priority - 1
        else:
            assert servo.scheduler == "other"
    helper.join()
    assert gc.isenabled() and gc.get_freeze_count() == 0
    assert os.sched_getscheduler(0) == policy_before
    assert helper_before == os.SCHED_OTHER


def test_an_exception_in_the_ticks_still_restores_the_thread():
    before = os.sched_getscheduler(0)
    with pytest.raises(RuntimeError):
        with WallClock(1_000_000).ticking():
            raise RuntimeError("the loop failed")
    assert os.sched_getscheduler(0) == before and gc.isenabled()


def test_the_wall_clock_reports_its_scheduler_and_keeps_its_deadlines_while_ticking():
    clock = WallClock(1_000_000)
    began = time.monotonic_ns()
    clock.start()
    with clock.ticking():
        for _ in range(200):
            clock.advance()
    assert time.monotonic_ns() - began >= 200 * 1_000_000  # never early
    assert clock.timing.ticks == 200
    assert clock.scheduler == ("fifo:10" if _fifo_permitted() else "other")


class _Chunker:
    source = "chunker"

    def __init__(self, horizon: int, dt_ns: int):
        self.horizon, self.dt_ns = horizon, dt_ns

    def reset(self) -> None:
        pass

    def content_hash(self) -> str:
        return "chunker"

    def infer(self, observation: Observation) -> ActionChunk:
        return ActionChunk(np.zeros((self.horizon, 2)), observation.t_ns, self.dt_ns)


@settings(max_examples=25, deadline=None)
@given(horizon=st.integers(1, 60), dt_ms=st.integers(1, 50), threshold=st.floats(0.0, 1.0),
       offsets=st.lists(st.integers(-5_000_000_000, 5_000_000_000), min_size=1, max_size=30))
def test_an_observation_is_due_exactly_when_the_queue_falls_to_the_threshold(horizon, dt_ms, threshold, offsets):
    worker = AsyncInference(_Chunker(horizon, dt_ms * 1_000_000), threshold=threshold)
    try:
        t_obs = 10_000_000_000
        worker.submit(Observation(t_obs, np.zeros(2), np.zeros(2)))
        deadline = time.monotonic() + 10
        while worker.take() is None:
            assert time.monotonic() < deadline
            time.sleep(0.0005)
        for offset in offsets + [k * dt_ms * 1_000_000 for k in range(horizon + 2)]:
            t = t_obs + offset
            assert worker.wants_observation(t) == (worker.remaining_steps(t) <= threshold * horizon), t
    finally:
        worker.close()
