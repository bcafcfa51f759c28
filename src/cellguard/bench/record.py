"""Figures for the fault record: cost per servo tick, bytes per hour, read time, 30-day index query.

Timings only (never asserted in tests). ``benchmarks/record.py`` prints them as JSON and
``cellguard bench --only record`` includes them.
"""

from __future__ import annotations

import gc
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from cellguard.bench.guard import RuckigProbe
from cellguard.control.events import Event
from cellguard.policy.chunk import ActionChunk
from cellguard.record.index import IndexWriter, cycle_row, cycles_above_baseline
from cellguard.record.reader import open_record
from cellguard.record.session import RunRecording
from cellguard.record.writer import RECORD_FILE, RecordConfig, Recorder
from cellguard.robot.state import State
from cellguard.runtime import Run
from cellguard.runtime.clock import WallClock
from cellguard.runtime.timing import SlowCalls
from cellguard.scenario import parse_scenario

DT_NS = 1_000_000
JOINTS = ("shoulder_pan", "shoulder_lift", "elbow", "wrist_flex", "wrist_roll", "gripper")
CYCLE_S = 20.0


def _synthetic_run(folder: Path, seconds: float, timed: bool = False, event_every_s: float = 600.0,
                   config: RecordConfig = RecordConfig()) -> list[int]:
    """Record ``seconds`` of a 6-joint arm at 1 kHz with 20 Hz chunks and a cycle every 20 s."""
    rng = np.random.default_rng(0)
    rec = Recorder.create(folder, joints=JOINTS, dt_ns=DT_NS, context={"servo_period_ns": DT_NS,
                          "record": config.to_dict()}, config=config)
    n, per_cycle, per_chunk = round(seconds * 1e9 / DT_NS), round(CYCLE_S * 1e9 / DT_NS), 50
    per_event = round(event_every_s * 1e9 / DT_NS)
    q = np.zeros(6)
    costs: list[int] = []
    actions = rng.normal(0.0, 1.0, (25, 6))
    for k in range(n):
        t = k * DT_NS
        cycle = k // per_cycle
        if k % per_cycle == 0:
            rec.cycle_begin(cycle, "acceptance" if cycle < 20 else "production", t)
        if k % per_chunk == 0:
            seen = {"part_in_camera": rng.normal(0, 1, 3), "fixture_in_camera": rng.normal(0, 1, 3)}
            rec.measurements(t, cycle, seen)
            rec.chunk(ActionChunk(actions + q, t, 20_000_000), t + 10_000_000, 10_000_000)
        q = q + rng.normal(0.0, 1e-3, 6)
        state = State(t, q, q * 0.1, q * 2.0, q * 0.5 + rng.normal(0.0, 0.02, 6))
        if timed:
            began = time.perf_counter_ns()
            rec.tick(cycle, q, q, state)
            costs.append(time.perf_counter_ns() - began)
        else:
            rec.tick(cycle, q, q, state)
        if k % per_event == per_event // 2:
            rec.event(Event(t, "position_clamp", "benchmark", joint="elbow", asked=1.0, sent=0.9), cycle)
        if k % per_cycle == per_cycle - 1:
            rec.cycle_end({"cycle": cycle, "phase": "acceptance" if cycle < 20 else "production", "success": True,
                           "features": {f"current_peak.{j}": float(rng.normal(1.0, 0.1)) for j in JOINTS}}, t)
    rec.close()
    return costs


def _stats(prefix: str, ns: list[int]) -> dict:
    us = np.asarray(ns, dtype=np.float64) * 1e-3
    return {f"{prefix}_us_median": float(np.median(us)), f"{prefix}_us_p99": float(np.percentile(us, 99)),
            f"{prefix}_us_max": float(us.max())}


class _Collections:
    """Garbage collections while it is installed (``gc.callbacks``): how many, and the longest [ns].

    A collection holds the GIL from start to end on whichever thread runs it, so the servo thread
    may wait for all of it.
    """

    def __init__(self):
        self.count, self.longest_ns, self._began = 0, 0, 0

    def __call__(self, phase: str, info: dict) -> None:
        if phase == "start":
            self._began = time.perf_counter_ns()
        else:
            self.count += 1
            self.longest_ns = max(self.longest_ns, time.perf_counter_ns() - self._began)


def _paced_run(folder: Path, seconds: float, event_every_s: float = 10.0) -> tuple[list[int], RunRecording,
                                                                                  _Collections, SlowCalls]:
    """The arm cell's recording fed at 1 kHz by the loop's own wall clock (the servo thread real-time
    where permitted, the collector run in idle time), as a real loop does.

    The ticks are synthetic (a random walk) so that only the recorder is timed; its writer process
    does the disk work meanwhile. Returns the servo-thread cost of each ``RunRecording.tick``, the
    recording, the garbage collections while the loop ran, and why the slow calls were slow.
    """
    rng = np.random.default_rng(0)
    run = Run(parse_scenario({"cell": "arm-pick-place", "seed": 3, "acceptance_cycles": 1, "production_cycles": 0}))
    run.clock = WallClock(DT_NS)  # the recording then drops a tick rather than wait, as on a robot
    recording = RunRecording.start(folder, run)
    n, per_cycle = round(seconds * 1e9 / DT_NS), round(CYCLE_S * 1e9 / DT_NS)
    per_event = round(event_every_s * 1e9 / DT_NS)
    q, costs, slow = np.zeros(6), [], SlowCalls()
    collections = _Collections()
    gc.callbacks.append(collections)
    run.clock.start()
    with run.clock.ticking():
        for k in range(n):
            t = k * DT_NS
            if k % per_cycle == 0:
                recording.begin_cycle(k // per_cycle, "acceptance", t)
            if k % per_event == per_event // 2:
                run.events.append(Event(t, "position_clamp", "benchmark", joint="elbow", asked=1.0, sent=0.9))
            q = q + rng.normal(0.0, 1e-3, 6)
            state = State(t, q, q * 0.1, q * 2.0, q * 0.5)
            usage = slow.before()
            began = time.perf_counter_ns()
            recording.tick(state.t_ns, q, q, state)
            costs.append(time.perf_counter_ns() - began)
            slow.after(usage, costs[-1])
            if k % per_cycle == per_cycle - 1:
                recording.end_cycle({"cycle": k // per_cycle, "phase": "acceptance", "success": True,
                                     "features": {}}, t)
            run.clock.advance()
    gc.callbacks.remove(collections)
    recording.close()
    return costs, recording, collections, slow


def tick_cost(seconds: float = 120.0) -> dict:
    """Recorder cost on the servo thread per tick (6 joints), against one ruckig call measured in the same run.

    ``tick_*``: ``RunRecording.tick`` in a paced 1 kHz loop, the writer process doing the rest;
    ``sync_tick_*``: the recorder called directly on the servo thread (flushes, chunk closing and
    zstd included), i.e. what the servo thread paid without a writer of its own. ``over_200us``: why the
    paced calls over 200 µs were slow (``SlowCalls``); ``waited`` would be the recorder's doing;
    ``on_cpu`` its work or the host's interrupts (the real-time benchmark's floor times a 1 µs row copy alike).
    """
    probe = RuckigProbe(len(JOINTS))  # one ruckig update from a random state: the servo path's reference
    probe.sample(2000)
    with tempfile.TemporaryDirectory() as tmp:
        costs, recording, collections, slow = _paced_run(Path(tmp), seconds)
    with tempfile.TemporaryDirectory() as tmp:
        sync = _synthetic_run(Path(tmp), seconds, timed=True, event_every_s=60.0)
    ruckig_us = probe.median_us()
    out = {**_stats("tick", costs), **_stats("sync_tick", sync), "ruckig_call_us_median": ruckig_us}
    for key in ("tick_us_median", "tick_us_p99", "tick_us_max", "sync_tick_us_p99", "sync_tick_us_max"):
        out[key.replace("_us", "") + "_per_ruckig_call"] = out[key] / ruckig_us
    return {**out, "ticks": len(costs), "ticks_over_200us": int(np.count_nonzero(np.asarray(costs) > 200_000)),
            "over_200us": slow.counts,
            "gc_collections": collections.count, "gc_longest_us": collections.longest_ns * 1e-3,
            "queue_high_water_ticks": recording.high_water, "writer_lag_ticks": recording.writer_lag,
            "ticks_dropped": recording.dropped,
            "servo_scheduler": recording.run.clock.scheduler,
            "record_failed": recording.failed}


def full_collection_cost(repeats: int = 5) -> dict:
    """CPU time of one full garbage collection with the arm cell loaded, outside and inside a recording [µs].

    A collection holds the GIL from start to end, so the servo thread waits for all of it; inside a
    recording the heap held at its start is frozen out of the collector. Thread CPU time (median of
    ``repeats``), so the figures do not depend on the machine's load.
    """
    def median_us() -> float:
        times = []
        for _ in range(repeats):
            began = time.thread_time_ns()
            gc.collect()
            times.append(time.thread_time_ns() - began)
        return statistics.median(times) * 1e-3

    run = Run(parse_scenario({"cell": "arm-pick-place", "seed": 3, "acceptance_cycles": 1, "production_cycles": 0}))
    tracked, outside = len(gc.get_objects()), median_us()
    with tempfile.TemporaryDirectory() as tmp:
        recording = RunRecording.start(Path(tmp), run)
        inside = median_us()
        recording.close()
    return {"gc_tracked_objects": tracked, "gc_full_collection_us": outside, "gc_full_collection_recording_us": inside}


def bytes_per_hour(cycles: int = 6) -> dict:
    """MB per hour of the real arm cell: decimated only, at the default rates, at full servo rate throughout.

    The default figure depends on how often events open full-rate windows in this run
    (``events_per_hour``); ``mb_per_event_window`` is what one window adds at most.
    """
    configs = {"continuous_only": RecordConfig(pre_trigger_s=0.0, post_trigger_s=0.0), "default": RecordConfig(),
               "full_rate": RecordConfig(decimated_hz=1000.0)}
    out, events_per_hour = {}, 0.0
    for name, config in configs.items():
        scenario = parse_scenario({"cell": "arm-pick-place", "seed": 3, "acceptance_cycles": cycles,
                                   "production_cycles": 0})
        with tempfile.TemporaryDirectory() as tmp:
            run = Run(scenario)
            run.recording = RunRecording.start(Path(tmp), run, config=config)
            for _ in range(cycles):
                run.cycle()
            run.recording.close()
            hours = run.cell.t_ns * 1e-9 / 3600
            out[name] = (Path(tmp) / RECORD_FILE).stat().st_size / hours / 1e6
            events_per_hour = len(run.events) / hours
    window_s = RecordConfig().pre_trigger_s + RecordConfig().post_trigger_s
    return {"mb_per_hour_continuous_only": out["continuous_only"], "mb_per_hour_default": out["default"],
            "mb_per_hour_full_rate": out["full_rate"], "events_per_hour_in_run": events_per_hour,
            "mb_per_event_window": (out["full_rate"] - out["continuous_only"]) * window_s / 3600,
            "gb_per_30_days_continuous_only": out["continuous_only"] * 24 * 30 / 1e3}


def read_one_cycle(hours: float = 1.0, repeats: int = 5) -> dict:
    """Open a record of ``hours`` (synthetic, 6 joints, events every 10 min) and read one cycle's ticks."""
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        began = time.perf_counter()
        _synthetic_run(folder, hours * 3600.0)
        write_s = time.perf_counter() - began
        size = (folder / RECORD_FILE).stat().st_size
        cycles = round(hours * 3600 / CYCLE_S)
        times, rows = [], 0
        for i in range(repeats):
            began = time.perf_counter()
            with open_record(folder) as rec:
                rows = len(rec.ticks(cycle=(i * 37) % cycles))
            times.append(time.perf_counter() - began)
    return {"record_hours": hours, "record_mb": size / 1e6, "write_s": write_s,
            "read_one_cycle_ms_median": statistics.median(times) * 1e3, "ticks_per_cycle_read": rows}


def query_30_days(days: int = 30, repeats: int = 3) -> dict:
    """"Every cycle whose peak elbow current is above the baseline's 99th percentile" over ``days`` days."""
    rng = np.random.default_rng(1)
    per_day = round(86400 / CYCLE_S)
    cycles = days * per_day
    names = [f"{kind}.{j}" for kind in ("current_peak", "current_rms", "tracking_rms", "tracking_max") for j in JOINTS]
    names += [f"extra_{i}" for i in range(30)]
    values = rng.normal(1.0, 0.1, (cycles, len(names)))
    elbow = names.index("current_peak.elbow")
    values[cycles // 2:, elbow] += np.linspace(0.0, 0.5, cycles - cycles // 2)  # drift, second half
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "index"
        began = time.perf_counter()
        index = IndexWriter(folder, epoch_wall_ns=1_790_000_000_000_000_000, part_rows=RecordConfig().index_part_rows)
        versions = {"policy_version": "p1", "calibration_version": "c1", "datum_version": "d1",
                    "context_version": "x1"}
        for i in range(cycles):
            t = round(i * CYCLE_S * 1e9)
            index.add("cycles", cycle_row(i, "acceptance" if i < 500 else "production", t, t + 19 * 10**9, True,
                                          versions, dict(zip(names, values[i].tolist()))))
        index.flush()
        build_s = time.perf_counter() - began
        times, hits = [], 0
        for _ in range(repeats):
            began = time.perf_counter()
            hits = len(cycles_above_baseline(folder, "current_peak.elbow", 0.99))
            times.append(time.perf_counter() - began)
        files = len(list(folder.glob("cycles/day=*/*.parquet")))
    return {"cycles": cycles, "days": days, "parquet_files": files, "index_build_s": build_s,
            "query_s_median": statistics.median(times), "cycles_found": hits}


def figures(quick: bool = False) -> dict:
    """Every record figure; ``quick`` shortens the recordings (not the 30-day query)."""
    return {**tick_cost(20.0 if quick else 120.0), **full_collection_cost(), **bytes_per_hour(3 if quick else 6),
            **read_one_cycle(0.25 if quick else 1.0), **query_30_days()}
