"""Benchmark figures measure what their names say: the guard's speed cap, soak growth, inference stalls,
the recorder writer's lag."""

from __future__ import annotations

import ctypes
import subprocess
import sys
import time
from pathlib import Path

import pytest
from record_synth import SlowDisk

from cellguard.control.guard import Guard
from cellguard.record.session import TAIL, RunRecording
from cellguard.runtime import Run
from cellguard.runtime.clock import SWITCH_INTERVAL_S
from cellguard.scenario import load_scenario

ROOT = Path(__file__).parents[1]
DEMO = ROOT / "src" / "cellguard" / "scenarios" / "demo.yaml"


@pytest.fixture
def benchmarks(monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT / "benchmarks"))


def test_the_guard_bench_times_ticks_with_the_speed_cap_in_force():
    """The rows without a cap keep their names; the ``capped`` rows ran the cap: it changed the outside
    stream's setpoints (the program at 1.6 times its speed moves the tool faster than 1 m/s), not the inside's."""
    from cellguard.bench.guard import SPEED_CAP, figures

    result = figures()
    assert set(result["tick_cost_in_ruckig_calls"]) == {"inside", "outside", "all", "capped"}
    assert set(result["tick_cost_in_ruckig_calls"]["capped"]) == {"inside", "outside"}
    assert result["tick_cost_us"]["capped"]["outside"]["ticks"] == result["tick_cost_us"]["outside"]["ticks"]
    assert result["speed_cap_m_s"] == SPEED_CAP == 1.0
    assert result["capped_changed_ticks_fraction"]["inside"] == 0.0
    assert result["capped_changed_ticks_fraction"]["outside"] > 0.1


def _return_free_heap() -> None:
    """glibc's malloc_trim: freed heap pages go back to the system (a full run's earlier tests left enough that a
    28 MiB leak grew resident memory by 2.6 MiB)."""
    try:
        ctypes.CDLL(None).malloc_trim(0)
    except (OSError, AttributeError):  # not glibc: nothing to return
        pass


def test_soak_growth_counts_the_tail_and_is_null_when_too_short(benchmarks, monkeypatch):
    """A 16 KiB leak per tick over 1.5 simulated hours at 1 s per tick: 1,800 ticks after the warm-up hour
    (28 MiB allocated; resident memory shows most of it), which the last whole hour (hour 1) alone hid as 0.0."""
    import soak

    leak, tick = [], Guard.tick
    monkeypatch.setattr(Guard, "tick", lambda self, *a, **k: leak.append(b"x" * 16384) or tick(self, *a, **k))
    _return_free_heap()  # else the leak may fill pages the tests before it freed, counted resident already
    result = soak.soak(1.5, 1000.0, 1000.0, None)
    assert result["servo_period_ms"] == 1000.0 and result["rss_growth_ticks"] == 1800
    assert result["rss_by_hour"][-1]["ticks"] == 5400 and result["rss_growth_mib"] >= 10  # RSS: pages, not bytes
    assert result["rss_growth_mib_per_million_ticks"] >= 10 / 1800 * 1e6  # the same 10 MiB over 1,800 ticks
    leak.clear()
    short = soak.soak(0.5, 1000.0, 1000.0, None)
    assert short["rss_growth_mib"] is None and short["rss_growth_mib_per_million_ticks"] is None


def test_inference_stalls_and_late_ticks_mean_the_same_in_every_mode(benchmarks):
    """sync: the ticks the loop waits for ``infer`` are late ticks, not stalls (its reference never ran out:
    50 ms of latency against 100 ms of chunk left); the switch interval is the real loop's."""
    import inference

    before = sys.getswitchinterval()
    try:
        result = inference.run("sync", 0.8, 0.05, 10)
        assert sys.getswitchinterval() <= SWITCH_INTERVAL_S
    finally:
        sys.setswitchinterval(before)
    assert result["stall_ticks"] == 0
    assert result["late_ticks"] >= 45 * (result["chunks"] - 1) and result["chunks"] >= 3


def test_inference_refuses_a_run_too_short_to_measure():
    done = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "inference.py"), "--seconds", "0.01"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert "--seconds 0.01: too short to measure" in done.stderr.splitlines()[-1]


def test_the_writers_lag_is_not_the_batching_interval(tmp_path):
    """A writer that takes each batch before the next tick: the ring still fills to a batch (``high_water``),
    while the writer never took a tick to take what it had been told to (``writer_lag``)."""
    run = Run(load_scenario(DEMO).model_copy(update={"acceptance_cycles": 2, "production_cycles": 0}))
    recording = RunRecording.start(tmp_path, run)
    state = run.cell.read()
    try:
        for k in range(1000):
            recording.tick(k * run.cell.dt_ns, state.q, state.q, state)
            end = time.monotonic() + 30
            while recording._ctl[TAIL] < recording._told and time.monotonic() < end:
                time.sleep(0.001)
    finally:
        recording.close()
        run.close()
    assert recording.high_water >= 50 and recording.writer_lag == 0


def test_a_stalled_writers_lag_grows_with_the_ticks_it_leaves_untaken(tmp_path):
    """On wall time, a writer stuck on a disk that takes 50 ms per write: behind what it was told to take
    for a batch at least (the ring then fills to the queue's 200 ticks and further ticks are dropped)."""
    run = Run(load_scenario(DEMO).model_copy(update={"acceptance_cycles": 2, "production_cycles": 0}), realtime=True)
    recording = RunRecording.start(tmp_path, run, opener=SlowDisk(0.05), queue_s=0.2)
    state = run.cell.read()
    try:
        for k in range(1000):
            recording.tick(k * 1_000_000, state.q, state.q, state)
    finally:
        recording.close()
        run.close()
    assert recording.dropped > 0 and 100 <= recording.writer_lag <= 200
