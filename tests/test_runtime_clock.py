"""The wall clock paces the loop; the same loop runs a simulated cell on wall time; inference in a process."""

from __future__ import annotations

import sys
import threading
import time
from functools import partial

import numpy as np
import pytest
from sim_server_util import sway_file

from cellguard.policy.async_inference import AsyncInference
from cellguard.policy.registry import make_policy
from cellguard.robot.registry import make_cell
from cellguard.runtime import Run
from cellguard.runtime.build import policy_in_process
from cellguard.runtime.clock import SWITCH_INTERVAL_S, WallClock
from cellguard.scenario import parse_scenario


def test_the_wall_clock_never_wakes_before_a_deadline_and_counts_every_tick():
    steps = []
    clock = WallClock(2_000_000, step=lambda: steps.append(time.monotonic_ns()))
    began = time.monotonic_ns()
    clock.start()
    for _ in range(50):
        clock.advance()
    assert len(steps) == 50 and clock.timing.ticks == 50
    assert time.monotonic_ns() - began >= 50 * 2_000_000  # never early: 50 periods at least
    assert clock.timing.summary()["period_error_us"]["p50"] >= 0.0
    assert clock.timing.overruns == clock.timing.summary()["overruns"]


def test_a_simulated_cell_runs_the_same_loop_on_wall_time(tmp_path):
    run = Run(parse_scenario({"cell": "arm-pick-place", "policy": f"replay:{sway_file(tmp_path / 's.npz')}",
                              "acceptance_cycles": 1, "production_cycles": 0,
                              "cycle": {"source": "time", "seconds": 0.5},
                              "realtime": {"overrun_budget": 1_000_000}}), realtime=True)
    began = time.monotonic_ns()
    outcome = run.cycle()
    run.close()
    assert run.clock.realtime and run.clock.timing.ticks >= 500
    assert time.monotonic_ns() - began >= 0.5e9  # simulated time did not run ahead of the wall
    assert outcome["cycle_time_s"] >= 0.5
    assert "timing" in run.summary()


def _answer_in_process(policy, factory, cell):
    """The first result of ``factory``'s policy in its own process (``policy``: the run's copy), within 60 s."""
    worker = AsyncInference(policy, worker="process", factory=factory)
    try:
        worker.submit(cell.observe())
        result, deadline = None, time.monotonic() + 60
        while result is None and time.monotonic() < deadline:
            time.sleep(0.01)
            result = worker.take()
        assert result is not None
        return result
    finally:
        worker.close()


def test_inference_in_its_own_process_answers_and_reports_failures():
    cell = make_cell("arm-pick-place")
    cell.begin_cycle(0)
    here = make_policy("scripted", cell)
    result = _answer_in_process(here, partial(policy_in_process, "scripted", "arm-pick-place", 0), cell)
    assert result.error is None
    assert result.chunk.actions.shape[1] == 6 and np.isfinite(result.chunk.actions).all()
    result = _answer_in_process(here, partial(policy_in_process, "replay:/nonexistent.npz", "arm-pick-place", 0), cell)
    assert result.chunk is None and "policy could not be built" in result.error


def test_the_inference_process_runs_only_the_policy_the_run_loaded():
    """The process loads the policy again; one whose content differs from the run's copy (the run's checks,
    record and release hash) is never run: each request answers why."""
    cell = make_cell("arm-pick-place")
    cell.begin_cycle(0)
    other = partial(policy_in_process, "scripted", "quadruped-turns", 0)  # another program than the run's
    result = _answer_in_process(make_policy("scripted", cell), other, cell)
    assert result.chunk is None and "policy in the inference process is not the run's" in result.error


def test_a_pause_between_stretches_of_ticks_is_counted_as_a_pause_not_as_a_late_tick():
    clock = WallClock(2_000_000, priority=None)
    clock.start()
    with clock.ticking():
        for _ in range(5):
            clock.advance()
    time.sleep(0.05)  # a cycle's end: features, the record's cycle row; the robot holds
    with clock.ticking():
        for _ in range(5):
            clock.advance()
    timing = clock.timing.summary()
    assert clock.timing.pauses == 1 and clock.timing.max_pause_ns >= 45_000_000
    assert timing["pauses_between_stretches"]["count"] == 1


def test_inside_a_stretch_the_loop_time_is_the_tick_grid_not_the_jittered_wake_up():
    # a reference sampled at wake-ups moves by velocity x jitter; at 1 kHz the tracker's finite
    # differences read that as tens of rad/s² and the guard takes over a smooth chunk
    clock = WallClock(1_000_000, priority=None)
    clock.start()
    with clock.ticking():
        times, overran = [clock.now()], []
        for _ in range(200):
            clock.advance()
            times.append(clock.now())
            overran.append(clock.timing.new_overrun)
    steps = np.diff(times)
    on_time = steps[~np.asarray(overran)]
    assert len(on_time) > 100 and (on_time == 1_000_000).all()  # exactly one period apart
    assert (steps >= 1_000_000).all()  # after an overrun the grid restarts later, never earlier
    assert abs(clock.now() - time.monotonic_ns()) < 50_000_000  # outside a stretch: monotonic time


def test_the_idle_window_is_open_while_the_servo_thread_sleeps_and_closed_while_a_tick_computes():
    clock = WallClock(2_000_000, priority=None)
    opened, stop = [], threading.Event()

    def watch():  # another thread: each window it sees open, and how long it has left then
        while not stop.is_set():
            clock.idle.wait_next(0.05)
            opened.append(clock.idle.time_left_ns())

    watcher = threading.Thread(target=watch)
    watcher.start()
    clock.start()
    inside = []
    with clock.ticking():
        for _ in range(50):
            inside.append(clock.idle.time_left_ns())  # the tick's own work: the window is closed
            clock.advance()
    stop.set()
    watcher.join()
    assert all(left < 0 for left in inside)
    windows = [left for left in opened if left < 10**15]  # the last one seen may be the end of the stretch
    assert len(windows) >= 40  # one window per tick's sleep (a thread may miss one while it is descheduled)
    assert max(windows) < 2_000_000  # each ends before the next deadline
    assert clock.idle.time_left_ns() > 10**15  # outside a stretch the window stays open
    for _ in range(3):  # ticks outside a stretch (a stop's settling time) leave it open too
        clock.advance()
    assert clock.idle.time_left_ns() > 10**15


def test_on_wall_time_the_servo_thread_waits_at_most_50_us_for_the_gil_whatever_the_rate():
    """A pure-Python policy on a thread holds the GIL until the switch interval ends; a quarter period
    (1.25 ms at 200 Hz) let the servo thread wait that long."""
    before = sys.getswitchinterval()
    try:
        for period_ns in (5_000_000, 1_000_000):
            sys.setswitchinterval(0.005)
            WallClock(period_ns).start()
            assert sys.getswitchinterval() == pytest.approx(SWITCH_INTERVAL_S) and SWITCH_INTERVAL_S <= 5e-5
    finally:
        sys.setswitchinterval(before)


class _FailsAfter:
    """The scripted arm program whose calls raise from the ``good``-th on."""

    def __init__(self, cell, good: int):
        self._policy, self.good, self.calls, self.source = make_policy("scripted", cell), good, 0, "test:fails"

    def reset(self):
        self._policy.reset()

    def content_hash(self):
        return self._policy.content_hash()

    def infer(self, observation):
        self.calls += 1
        if self.calls > self.good:
            raise RuntimeError("the policy server answered 500")
        return self._policy.infer(observation)


@pytest.mark.parametrize("policy_hz", [10, 50])
def test_on_wall_time_the_policy_is_asked_at_most_at_its_cadence_even_when_it_fails(policy_hz):
    """policy_hz was ignored on wall time, and a failed call was repeated on every servo tick (2970 events in
    3 s: a thousand requests a second to a remote policy)."""
    scenario = parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 0,
                               "policy_hz": policy_hz, "cycle": {"source": "time", "seconds": 1.0},
                               "guard": {"watchdog_s": 5.0}, "realtime": {"overrun_budget": 1_000_000}})
    run = Run(scenario, realtime=True)
    run.policy = _FailsAfter(run.cell, good=3)  # the warm-up and the first two requests answer
    run.cycle()
    run.close()
    seconds = run.clock.timing.ticks * run.cell.dt_ns * 1e-9
    failed = sum(e.kind == "inference_failed" for e in run.events)
    assert failed >= 3 and run.policy.calls <= seconds * policy_hz + 2


def test_a_policy_process_that_dies_is_reported_with_its_exit_code():
    """The message read the exit code before the process was reaped: 'exit code None'."""
    from cellguard.policy.async_inference import PolicyProcess

    cell = make_cell("arm-pick-place")
    cell.begin_cycle(0)
    sha256 = make_policy("scripted", cell).content_hash()
    remote = PolicyProcess(partial(policy_in_process, "scripted", "arm-pick-place", 0), sha256)
    try:
        assert remote.infer(cell.observe()).actions.shape[1] == 6
        remote._process.kill()
        with pytest.raises(RuntimeError, match=r"^policy process ended \(exit code -9\)$"):
            remote.infer(cell.observe())
    finally:
        remote.close()


def test_policy_faults_of_a_simulated_cell_act_on_wall_time_too():
    """--realtime: a policy_nan fault crashed the run (the worker had no corrupt_pending: no summary.json) and a
    policy_latency fault was silently ignored while the ground truth listed it."""
    scenario = parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 1,
                               "cycle": {"source": "time", "seconds": 1.5}, "guard": {"watchdog_s": 1.0},
                               "realtime": {"overrun_budget": 1_000_000},
                               "faults": [{"kind": "policy_latency", "at_cycle": 1, "ms": 150},
                                          {"kind": "policy_nan", "at_cycle": 1}]})
    run = Run(scenario, realtime=True)
    try:
        before, after = run.cycle(), run.cycle()
    finally:
        run.close()
    assert before["inference"]["wall_ms_mean"] < 100 <= 150 <= after["inference"]["wall_ms_mean"]
    assert [e.kind for e in run.events].count("chunk_rejected") == 1
