"""The start-up latency check counts when the NEXT chunk arrives: one request at a time, the next observation
waits for this chunk, the policy's period and (on a worker) until the chunk runs low. Counting the latency alone
let through 298 ms on the scripted arm's 500 ms chunks, at which every chunk ended before the next arrived; counting
the blend too refused what ran (a next chunk inside the blend only shortens it)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from cellguard.policy.async_inference import AsyncInference
from cellguard.policy.chunk import ActionChunk
from cellguard.robot.registry import make_cell
from cellguard.robot.state import Observation
from cellguard.runtime import Run
from cellguard.runtime.inference import SimulatedInference, WorkerInference
from cellguard.runtime.startup import StartupRefused, check_startup
from cellguard.scenario import parse_scenario

MS = 1_000_000


class _Held:
    """A policy that answers every observation with the pose ``q``, held for ``h`` steps of 20 ms."""

    source = "test:held"

    def __init__(self, q, h: int = 25):
        self.q, self.h = np.asarray(q, dtype=np.float64), h

    def reset(self):
        pass

    def content_hash(self):
        return "0" * 64

    def infer(self, observation):
        return ActionChunk(np.tile(self.q, (self.h, 1)), observation.t_ns, 20 * MS)


def _chunk(t_obs_ns: int = 0) -> ActionChunk:
    return ActionChunk(np.zeros((25, 6)), t_obs_ns, 20 * MS)  # the scripted arm's: 25 steps of 20 ms


def test_a_latency_at_which_every_chunk_runs_out_is_refused():
    """250 ms on 500 ms chunks at 20 Hz: the next observation goes when this chunk is in (251 ms), its chunk 251 ms
    later: 502 ms, past the 300 ms before the blend. The latency alone (251 ms) fitted; so does it with no spacing
    given (the least: until the chunk is taken)."""
    with pytest.raises(StartupRefused, match=r"latency 250 ms plus one servo period 1 ms .* the next one, asked for "
                                             r"251 ms after this one's observation .* would arrive 502 ms after it"):
        check_startup(object(), None, _chunk(), 250 * MS, MS)
    check_startup(object(), None, _chunk(), 240 * MS, MS)  # 482 ms: the blend shortened, no step missing


def test_a_short_chunk_asked_for_at_10_hz_is_refused_before_the_robot_moves():
    """100 ms chunks at 10 Hz on simulated time: each ended 11 ms before the next arrived (the guard braked the
    reference at every chunk); the check took the 10 ms latency alone against the 50 ms budget and moved."""
    q0 = make_cell("arm-pick-place").q_home
    run = Run(parse_scenario({"cell": "arm-pick-place", "policy_hz": 10, "acceptance_cycles": 1, "production_cycles": 0,
                              "cycle": {"source": "time", "seconds": 1.0}}), policy_factory=lambda: _Held(q0, h=5))
    with pytest.raises(StartupRefused, match=r"latency 10 ms plus one servo period 1 ms .* asked for 100 ms after this "
                                             r"one's observation .* would arrive 111 ms after it, past its horizon 100"):
        run.cycle()
    assert [e.kind for e in run.events][-1] == "startup_refused"
    assert np.abs(run.cell.read().q - q0).max() < 1e-3


def test_a_simulated_latency_fault_is_still_no_refusal():
    """On simulated time the check takes the healthy latency: a latency fault is an incident to diagnose."""
    run = Run(parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 0,
                              "cycle": {"source": "time", "seconds": 0.5},
                              "faults": [{"kind": "policy_latency", "at_cycle": 0, "ms": 280}]}))
    run.cycle()
    assert "startup_refused" not in [e.kind for e in run.events]


def test_a_worker_counts_its_wait_until_the_chunk_runs_low():
    """LeRobot's threshold 0.5: the next observation goes once 12 of 25 steps are left, 260 ms in, whatever the
    latency below it; the same time at which ``wants_observation`` turns true."""
    worker = AsyncInference(_Held(np.zeros(6)), threshold=0.5)
    try:
        inference = WorkerInference(worker, 50 * MS)
        assert inference.spacing_ns(11 * MS, _chunk()) == 260 * MS
        assert inference.spacing_ns(300 * MS, _chunk()) == 300 * MS
        worker.submit(Observation(40 * MS, np.zeros(6), np.zeros(6)))
        for _ in range(500):  # bounded: 5 s
            if worker.take() is not None:
                break
            time.sleep(0.01)
        wait = worker.wait_ns(_chunk(40 * MS))
        assert not worker.wants_observation(40 * MS + wait - 1) and worker.wants_observation(40 * MS + wait)
    finally:
        worker.close()
    check_startup(object(), None, _chunk(), 230 * MS, MS, inference.spacing_ns(231 * MS, _chunk()))  # 491 ms
    with pytest.raises(StartupRefused, match=r"latency 240 ms .* asked for 260 ms after .* would arrive 501 ms"):
        check_startup(object(), None, _chunk(), 240 * MS, MS, inference.spacing_ns(241 * MS, _chunk()))


def test_in_simulated_time_the_policy_period_spaces_the_requests():
    """At 10 Hz a 10 ms policy's next chunk comes 111 ms after this one's observation."""
    assert SimulatedInference(_Held(np.zeros(6)), 100 * MS).spacing_ns(11 * MS, _chunk()) == 100 * MS


def test_a_watchdog_the_chunks_cannot_feed_is_refused():
    """The gap between chunks is the spacing plus one servo period (a chunk is taken at the next tick)."""
    with pytest.raises(StartupRefused, match=r"guard.watchdog_s 300 ms is not longer than the time between chunks, "
                                             r"up to 301 ms .* set guard.watchdog_s above 301 ms"):
        check_startup(object(), None, _chunk(), 10 * MS, MS, 300 * MS, watchdog_ns=300 * MS)
    check_startup(object(), None, _chunk(), 10 * MS, MS, 298 * MS, watchdog_ns=300 * MS)  # 299 ms: fed in time


@pytest.mark.parametrize("watchdog_s", [None, 0.8])
def test_one_second_chunks_on_a_worker_need_a_watchdog_longer_than_half_a_chunk(watchdog_s):
    """1 s chunks on wall time: the worker asks again 500 ms in, so the default 300 ms watchdog stopped the robot
    at every chunk (six watchdog stops and five resumes in 3 s); a watchdog above the gap runs without one."""
    q0 = make_cell("arm-pick-place").q_home
    run = Run(parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 0,
                              "cycle": {"source": "time", "seconds": 1.5}, "realtime": {"overrun_budget": 1_000_000},
                              **({"guard": {"watchdog_s": watchdog_s}} if watchdog_s else {})}),
              realtime=True, policy_factory=lambda: _Held(q0, h=50))
    if watchdog_s is None:
        with pytest.raises(StartupRefused, match=r"guard.watchdog_s 300 ms .* up to 501 ms"):
            run.cycle()
        assert [e.kind for e in run.events][-1] == "startup_refused"
    else:
        run.cycle()
        kinds = [e.kind for e in run.events]
        assert "watchdog_stop" not in kinds and "startup_refused" not in kinds
