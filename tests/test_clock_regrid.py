"""Inside a stretch of ticks, work that is no tick (the guard built anew where an approach left the robot, at rest)
is a pause once the clock is regridded, not a late tick: the cycle's first tick after an approach woke 5 to 23 ms
late on wall time, an overrun, and ``overrun_budget: 0`` stopped every run that needed an approach."""

from __future__ import annotations

import time

from cellguard.runtime.clock import WallClock

MS = 1_000_000


def _stretch(regrid: bool) -> WallClock:
    clock = WallClock(MS, priority=None)
    clock.start()
    with clock.ticking():
        for _ in range(5):
            clock.advance()
        time.sleep(0.03)  # 30 ms of work between two ticks
        if regrid:
            clock.regrid()
        clock.advance()
    return clock


def test_work_between_two_ticks_is_a_pause_once_regridded():
    timing = _stretch(regrid=True).timing
    assert timing.pauses == 1 and timing.max_pause_ns >= 25 * MS
    assert timing.max_late_ns < 20 * MS  # no tick carries the 30 ms


def test_without_it_the_next_tick_carries_the_work_as_lateness():
    timing = _stretch(regrid=False).timing
    assert timing.max_late_ns >= 25 * MS and timing.overruns >= 1


def test_the_first_tick_after_an_approach_on_wall_time_is_not_late(tmp_path, monkeypatch):
    """The loop regrids once it has built the guard where the approach left the robot (made slow here: 30 ms)."""
    import numpy as np

    import cellguard.runtime.loop as loop
    from cellguard.robot.registry import make_cell
    from cellguard.runtime import Run
    from cellguard.scenario import parse_scenario

    away = np.array(make_cell("arm-pick-place").read().q, dtype=np.float64) + np.array([0.3, 0, 0, 0, 0, 0])
    np.savez(tmp_path / "away.npz", t=np.arange(0.0, 3.0, 0.1), actions=np.tile(away, (30, 25, 1)), dt=np.float64(0.02))
    built = loop.build_guard

    def slow(*args, **kwargs):
        time.sleep(0.03)
        return built(*args, **kwargs)

    monkeypatch.setattr(loop, "build_guard", slow)
    run = Run(parse_scenario({"cell": "arm-pick-place", "policy": f"replay:{tmp_path / 'away.npz'}",
                              "acceptance_cycles": 1, "production_cycles": 0,
                              "cycle": {"source": "time", "seconds": 0.5}}), realtime=True)
    try:
        run.run_cycles()
    finally:
        run.close()
    assert run.events.has("approach_done")
    assert run.clock.timing.max_late_ns < 20 * MS
