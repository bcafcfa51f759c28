"""On wall time a run's cycles are one stretch of ticks: a cycle's end is work inside the period grid (a late tick
where it is slow, never a pause hidden from the figures), the servo thread stays real-time across it, and the
retreat's brake from motion is played in that stretch too; its way home, checked at rest, follows a pause. Timing
is not asserted: only where time is counted."""

from __future__ import annotations

import gc
import os
import threading
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cellguard.runtime import Run
from cellguard.runtime.clock import WallClock
from cellguard.runtime.loop import _wall_latency
from cellguard.runtime.servo_thread import COLLECT_EVERY, PRIORITY, ServoThread
from cellguard.scenario import parse_scenario
from test_runtime_servo_thread import _fifo_permitted

MS = 1_000_000


def test_work_between_stretches_joined_is_ticks_not_a_pause():
    """30 ms of work between two stretches inside ``one_stretch``: no pause, the next tick carries it as lateness,
    and the servo thread stays a ticking one in between; all undone at the end."""
    clock = WallClock(MS, priority=None)
    clock.start()
    with clock.one_stretch():
        for _ in range(2):
            with clock.ticking():
                for _ in range(5):
                    clock.advance()
            assert clock._servo.active and not gc.isenabled()
            time.sleep(0.03)
    assert clock.timing.pauses == 0 and clock.timing.max_late_ns >= 25 * MS
    assert not clock._servo.active and gc.isenabled()


def _run(**cycle) -> Run:
    return Run(parse_scenario({"cell": "arm-pick-place", "policy": "scripted", "acceptance_cycles": 3,
                               "production_cycles": 0, "cycle": {"source": "time", "seconds": 0.3, **cycle}}),
               realtime=True)


def test_the_cycles_of_a_run_on_wall_time_and_the_retreats_brake_are_one_stretch():
    """A time cycle of the taught program ends mid-motion: the retreat brakes the command to rest in the cycles'
    stretch (begun after a pause, the robot held its last setpoint at speed: 0.7 to 3.9 ms at 1 kHz), then plans and
    checks its way home at rest (a pause)."""
    run = _run()
    seen, plays = [], []
    play = run._play

    def watched(plan, name, *args, **kwargs):
        plays.append((name, plan.settles or plan.brakes, run.clock._servo is not None and run.clock._servo.active))
        return play(plan, name, *args, **kwargs)

    run._play = watched
    try:
        run.run_cycles(lambda outcome: seen.append((run.clock._servo.active, gc.isenabled())))
    finally:
        run.close()
    assert seen == [(True, False)] * 3  # every cycle's end (and the caller's look at it) inside the ticks
    timing = run.summary()["timing"]
    assert timing["between_cycles_ms"]["count"] == 2
    assert not run.clock._servo.active and gc.isenabled()
    assert run.events.has("retreat_done")
    braking = [active for name, brakes, active in plays if name == "retreat" and brakes]
    assert braking == [True], plays  # the brake from motion, played inside the cycles' stretch


def test_a_cycle_monitor_on_wall_time_is_a_pause_not_a_late_tick():
    """A simulated cell's residual monitor replays the cycle between its ticks: work that is no tick (the grid is
    started again after it), as before the cycles were one stretch."""
    run = _run()
    run.cycle_monitors.append(lambda ticks, outcome: time.sleep(0.03))
    try:
        run.run_cycles()
    finally:
        run.close()
    assert run.clock.timing.pauses >= 3 and run.clock.timing.max_pause_ns >= 25 * MS


def test_the_callers_work_at_a_cycles_end_is_a_pause_not_an_overrun():
    """``on_cycle`` (the CLI's progress bar: 2 to 3 ms as it first draws) is the caller's work, not the loop's: with
    ``overrun_budget: 0`` it stopped every CLI run against the sim-server at its second cycle."""
    run = _run()
    try:
        run.run_cycles(lambda outcome: time.sleep(0.03))
    finally:
        run.close()
    assert run.clock.timing.pauses >= 3 and run.clock.timing.max_pause_ns >= 25 * MS
    assert run.clock.timing.max_late_ns < 25 * MS


@pytest.mark.skipif(not _fifo_permitted(), reason="SCHED_FIFO not permitted here")
def test_a_thread_started_while_ticking_gets_the_priority_below_at_the_next_collection():
    """A stretch may last a whole run: a thread started during it (a CLI's progress display, at the first cycle's
    end) would stay ordinary, and holding the GIL while the OS preempts it, stall the servo thread."""
    done = threading.Event()
    with ServoThread(PRIORITY) as servo:
        helper = threading.Thread(target=done.wait, args=(5,))
        helper.start()
        try:
            assert os.sched_getscheduler(helper.native_id) != os.SCHED_FIFO
            for _ in range(COLLECT_EVERY):
                servo.collect_if_idle(10 * MS)
            assert os.sched_getscheduler(helper.native_id) & ~getattr(os, "SCHED_RESET_ON_FORK", 0) == os.SCHED_FIFO
            assert os.sched_getparam(helper.native_id).sched_priority == PRIORITY - 1
        finally:
            done.set()
            helper.join()


@settings(max_examples=300, deadline=None)
@given(st.lists(st.integers(0, 10 ** 12), max_size=400))
def test_a_cycles_inference_figures_equal_numpys(wall_ns):
    """The p99 is taken without ``np.percentile`` (70 to 300 µs a call at a cycle's end): the same numbers."""
    ms = np.asarray(wall_ns, dtype=np.float64) * 1e-6
    assert _wall_latency(wall_ns) == {"chunks": len(wall_ns), "wall_ms_mean": float(ms.mean()) if wall_ns else 0.0,
                                      "wall_ms_p99": float(np.percentile(ms, 99)) if wall_ns else 0.0,
                                      "wall_ms_max": float(ms.max()) if wall_ns else 0.0}
