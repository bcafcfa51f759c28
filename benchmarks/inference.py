"""Per-chunk inference latency and servo stalls, synchronous versus async inference, side by side.

The arm cell runs in real time (a 1 ms tick paced by the wall clock) with the scripted program
behind a policy that takes ``--latency-ms`` per call and answers ``--horizon`` steps of 20 ms.
A new observation is sent when the steps left fall to half the horizon, in every mode.

- sync: the servo loop calls ``infer`` itself; the ticks that pass while it waits, the drive
  holding its last setpoint, are late ticks.
- async: ``AsyncInference`` runs ``infer`` on its own thread; the loop never waits for it.
- async-process: the same, with the policy in its own process (``worker="process"``).

Two figures, defined alike in every mode and counted from the first chunk on (before it the cell
has not started moving): a ``stall`` tick's reference has run past the end of the newest chunk
(the policy starved the executor); a ``late`` tick was not served within one period of its
deadline (the loop waited for ``infer``, or for the interpreter). The interpreter's switch interval
is lowered as the real loop lowers it (``runtime.clock.SWITCH_INTERVAL_S``). With ``--busy`` the
policy spends its latency in pure-Python work that holds the GIL instead of sleeping: the thread
worker then competes with the servo loop for the interpreter, the process worker does not.

Prints one JSON document. Usage: ``python benchmarks/inference.py [--seconds 5]``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from functools import partial

import numpy as np

from cellguard.control.executor import Executor
from cellguard.policy.async_inference import AsyncInference
from cellguard.policy.scripted_arm import ScriptedArmPolicy
from cellguard.robot.arm_cell import ArmPickPlace
from cellguard.runtime.clock import SWITCH_INTERVAL_S

THRESHOLD = 0.5
STEP_S = 0.02  # the scripted program's step [s]
WARM_UP_S = 60.0  # the policy's first call, off the clock, may take this long


class SlowPolicy:
    """The scripted program, made to take ``latency_s`` of wall time per call (a big model)."""

    source = "scripted+sleep"

    def __init__(self, policy, latency_s: float, busy: bool = False):
        self.policy, self.latency_s, self.busy = policy, latency_s, busy

    def reset(self) -> None:
        self.policy.reset()

    def content_hash(self) -> str:
        return self.policy.content_hash()

    def infer(self, observation):
        if self.busy:
            end, acc = time.perf_counter() + self.latency_s, 0
            while time.perf_counter() < end:
                for i in range(1000):
                    acc = (acc + i * i) % 7919
        else:
            time.sleep(self.latency_s)
        return self.policy.infer(observation)


def slow_policy(latency_s: float, horizon: int, busy: bool, calibration: dict) -> SlowPolicy:
    """The benchmark's policy, built where it runs (this process or the inference process)."""
    return SlowPolicy(ScriptedArmPolicy(horizon=horizon, calibration=calibration), latency_s, busy)


def _steps_left(step_times: np.ndarray, t_ns: int) -> int:
    return int(np.count_nonzero(step_times > t_ns))


def _stalled(step_times: np.ndarray, t_ns: int) -> bool:
    """The reference at ``t_ns`` has run past the end of the newest chunk (none yet: the cell waits, no stall)."""
    return len(step_times) > 0 and _steps_left(step_times, t_ns) == 0


def shortest_seconds(latency_s: float, horizon: int) -> float:
    """Wall time for two chunks: the first, and the one asked for when half of it is left."""
    return 2 * latency_s + THRESHOLD * horizon * STEP_S


def run(mode: str, seconds: float, latency_s: float, horizon: int, busy: bool = False) -> dict:
    sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL_S))  # as WallClock.start does
    cell = ArmPickPlace(seed=0)
    cell.begin_cycle(0)
    factory = partial(slow_policy, latency_s, horizon, busy, cell.context())
    policy = factory()
    executor = Executor(cell.profile, cell.read().q, cell.dt_ns)
    worker = None
    if mode.startswith("async"):
        worker = AsyncInference(policy, THRESHOLD, worker="process" if mode == "async-process" else "thread",
                                factory=factory)
        if not worker.warm_up(cell.observe(), WARM_UP_S):
            raise SystemExit(f"{mode}: the policy's first call has not answered in {WARM_UP_S:g} s")
    dt, n_ticks = cell.dt_ns, round(seconds * 1e9 / cell.dt_ns)
    step_times = np.zeros(0, dtype=np.int64)
    latencies, depths, stalls, late, dropped, sent = [], [], 0, 0, 0, cell.read().q
    start, k = time.perf_counter_ns(), 0
    while k < n_ticks:
        lag = time.perf_counter_ns() - (start + k * dt)
        if lag < 0:
            time.sleep(-lag * 1e-9)
        elif lag > dt:
            late += len(step_times) > 0
        t = cell.t_ns
        chunk = None
        if worker is not None:
            result = worker.take()
            if result is not None and result.chunk is not None:
                chunk = result.chunk
                latencies.append(result.latency_ns)
                depths.append(result.queue_depth)
            if worker.wants_observation(t):
                worker.submit(cell.observe())
        elif len(step_times) == 0 or _steps_left(step_times, t) <= THRESHOLD * len(step_times):
            depths.append(_steps_left(step_times, t))
            began = time.perf_counter_ns()
            chunk = policy.infer(cell.observe())
            latencies.append(time.perf_counter_ns() - began)
            for _ in range(min(latencies[-1] // dt, n_ticks - k)):  # the drive holds while the loop waits
                late += len(step_times) > 0
                stalls += _stalled(step_times, cell.t_ns)
                cell.write(sent)
                cell.step()
                k += 1
        if chunk is not None:
            now = cell.t_ns
            step_times = chunk.t_obs_ns + (np.arange(chunk.horizon, dtype=np.int64) + 1) * chunk.dt_ns
            dropped += int(np.count_nonzero(step_times <= now))
            executor.push(chunk, now)
        stalls += _stalled(step_times, cell.t_ns)
        sent = cell.write(executor.reference(cell.t_ns))
        cell.step()
        k += 1
    if worker is not None:
        worker.close()
    ms = np.array(latencies) * 1e-6
    return {
        "mode": mode, "ticks": n_ticks, "chunks": len(latencies),
        "latency_ms": {"mean": float(ms.mean()), "p50": float(np.median(ms)), "p99": float(np.percentile(ms, 99)),
                       "max": float(ms.max())},
        "stall_ticks": stalls, "stall_fraction": stalls / n_ticks, "late_ticks": late, "late_fraction": late / n_ticks,
        "queue_depth_at_request": {"min": int(min(depths)), "mean": float(np.mean(depths))},
        "stale_steps_dropped": dropped,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="wall time per mode")
    parser.add_argument("--latency-ms", type=float, default=100.0, help="policy time per call")
    parser.add_argument("--horizon", type=int, default=50, help="steps of 20 ms per chunk")
    parser.add_argument("--busy", action="store_true", help="pure-Python work instead of a sleep (holds the GIL)")
    args = parser.parse_args()
    if not (args.latency_ms >= 0 and args.horizon >= 2):  # NaN included
        parser.error(f"--latency-ms must be at least 0 and --horizon at least 2, got {args.latency_ms} and "
                     f"{args.horizon}")
    shortest = shortest_seconds(args.latency_ms * 1e-3, args.horizon)
    if not args.seconds >= shortest:
        parser.error(f"--seconds {args.seconds}: too short to measure; at least {shortest:g} s (two chunks: "
                     f"twice the latency and half of a {args.horizon}-step chunk)")
    results = [run(mode, args.seconds, args.latency_ms * 1e-3, args.horizon, args.busy)
               for mode in ("sync", "async", "async-process")]
    print(json.dumps({"benchmark": "inference", "policy_latency_ms": args.latency_ms, "busy": args.busy,
                      "horizon": args.horizon, "step_ms": STEP_S * 1e3, "threshold": THRESHOLD, "servo_period_ms": 1,
                      "results": results}, indent=1))


if __name__ == "__main__":
    main()
