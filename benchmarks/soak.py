"""Soak: a simulated day of ticks through the Guard (and the recorder) with resident memory printed (JSON).

Runs that never end must not grow. The arm profile's guard gets a synthetic stream for
``--hours`` of simulated time at a coarse servo period (``--dt-ms``, default 200 ms: the reduced
cost, 432 k ticks for 24 h): a chunk every ``--chunk-ms`` (default 1 s) of a slow sinusoidal
program, and every simulated minute a disturbance in turn (a NaN chunk, a late chunk, a protective
stop of category 2, or once an hour 0 followed by an operator reset, a silence that trips the
watchdog), so that every event path runs all day. With
``--record DIR`` the ticks and events are also written by the recorder (decimated stream, event
windows, index). Prints the resident set size (VmRSS) at each simulated hour and at the end, and
its growth from the first hour (a warm-up) to the end, per million ticks: ``null`` for a run of an
hour or less, which has nothing after the warm-up to compare.

    python benchmarks/soak.py [--hours 24] [--dt-ms 200] [--chunk-ms 1000] [--record DIR]
"""

from __future__ import annotations

import argparse
import json
import time
from collections import Counter
from pathlib import Path

import numpy as np

from cellguard.control.config import GuardConfig
from cellguard.control.guard import Guard
from cellguard.policy.chunk import ActionChunk
from cellguard.robot.protocol import SafetyInputs
from cellguard.robot.registry import make_cell
from cellguard.robot.state import State

HOUR_NS = 3_600_000_000_000
MINUTE_NS = 60_000_000_000


def rss_mib() -> float:
    """Resident set size now [MiB], from /proc."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def _recorder(folder: Path, profile, dt_ns: int):
    from cellguard.record.writer import Recorder

    return Recorder.create(folder, joints=profile.joint_names, dt_ns=dt_ns, context={"soak": True})


def soak(hours: float, dt_ms: float, chunk_ms: float, record: Path | None) -> dict:
    cell = make_cell("arm-pick-place")
    profile, q0 = cell.profile, cell.read().q
    dt_ns, chunk_ns, horizon = round(dt_ms * 1e6), round(chunk_ms * 1e6), 25
    step_ns = max(chunk_ns // 10, 1_000_000)
    watchdog_s = 3 * chunk_ms * 1e-3
    guard = Guard(profile, q0, dt_ns, GuardConfig(watchdog_s=watchdog_s))
    amplitude = 0.05 * (profile.q_max - profile.q_min)
    recorder = None if record is None else _recorder(record, profile, dt_ns)
    zero = np.zeros(profile.dof)
    events: Counter = Counter()
    ticks = round(hours * HOUR_NS / dt_ns)
    per_hour = max(1, round(HOUR_NS / dt_ns))
    samples: list[dict] = []  # VmRSS at each whole hour and at the end

    def sample(done: int) -> None:
        samples.append({"hour": round(done * dt_ns / HOUR_NS, 3), "ticks": done, "rss_mib": round(rss_mib(), 1)})

    began = time.perf_counter()
    for k in range(ticks):
        t = k * dt_ns
        minute, into = divmod(t, MINUTE_NS)
        disturbance = minute % 4  # 0: NaN chunk, 1: late chunk, 2: protective stop, 3: silence -> watchdog
        silent = disturbance == 3 and into < 3 * watchdog_s * 1e9
        if t % chunk_ns == 0 and not silent:
            steps = (t + (np.arange(horizon) + 1) * step_ns) * 1e-9
            actions = q0 + amplitude * np.sin(2 * np.pi * steps[:, None] / 20.0)
            t_obs = t - 400_000_000 if disturbance == 1 and into < chunk_ns else t
            if disturbance == 0 and into < chunk_ns:
                actions[3, 1] = np.nan
            for e in guard.push(ActionChunk(actions, t_obs, step_ns), t):
                events[str(e.kind)] += 1
                if recorder is not None:
                    recorder.event(e, minute)
        stop = (0 if minute % 60 == 2 else 2) if disturbance == 2 and 1e9 <= into < 3e9 else None
        setpoint, evs = guard.tick(t, None, SafetyInputs(stop=stop))
        events.update(str(e.kind) for e in evs)
        if not guard.power and stop is None:
            guard.reset(setpoint)  # the operator, once the stop input is released
        if recorder is not None:
            for e in evs:
                recorder.event(e, minute)
            recorder.tick(minute, guard.reference, setpoint, State(t, setpoint, zero, zero, zero))
        if (k + 1) % per_hour == 0:
            sample(k + 1)
    if ticks % per_hour:  # the tail after the last whole hour counts too
        sample(ticks)
    if recorder is not None:
        recorder.close()
    return {"simulated_hours": hours, "servo_period_ms": dt_ms, "chunk_ms": chunk_ms, "ticks": ticks,
            "events": dict(events), "recorded": record is not None, **_growth(samples),
            "wall_s": round(time.perf_counter() - began, 1), "rss_by_hour": samples}


def _growth(samples: list[dict]) -> dict:
    """VmRSS after the warm-up hour and at the end [MiB], and the growth between them, also per million
    ticks; the growth is None when the run ended within the warm-up hour (a 0.0 there would hide a leak)."""
    first, last = samples[0], samples[-1]
    ticks = last["ticks"] - first["ticks"]
    growth = round(last["rss_mib"] - first["rss_mib"], 1) if ticks else None
    return {"rss_start_mib": first["rss_mib"], "rss_end_mib": last["rss_mib"], "rss_growth_mib": growth,
            "rss_growth_ticks": ticks,
            "rss_growth_mib_per_million_ticks": None if growth is None else round(growth / ticks * 1e6, 2)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=24.0, help="simulated time [h]")
    parser.add_argument("--dt-ms", type=float, default=200.0, help="servo period [ms] (coarse: the reduced cost)")
    parser.add_argument("--chunk-ms", type=float, default=1000.0, help="a chunk every this long [ms]")
    parser.add_argument("--record", type=Path, default=None, help="also write a record into this folder")
    args = parser.parse_args()
    if not (args.hours > 0 and args.dt_ms > 0 and args.chunk_ms > 0):  # NaN included
        parser.error(f"--hours, --dt-ms and --chunk-ms must be positive, got {args.hours}, {args.dt_ms} and "
                     f"{args.chunk_ms}")
    if args.hours * HOUR_NS < args.dt_ms * 1e6:
        parser.error(f"--hours {args.hours} is shorter than one servo period (--dt-ms {args.dt_ms})")
    print(json.dumps(soak(args.hours, args.dt_ms, args.chunk_ms, args.record), indent=1))


if __name__ == "__main__":
    main()
