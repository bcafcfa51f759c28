"""What a scenario names, built for the loop: the robot, the clock, the inference worker."""

from __future__ import annotations

from functools import partial

from cellguard.robot.registry import make_cell
from cellguard.runtime.clock import LockStepClock, SimClock, WallClock
from cellguard.runtime.inference import SimulatedInference, WorkerInference


def make_robot(scenario):
    """``robot: sim`` is the scenario's simulated cell; anything else a bridge (``SCHEME:ARGUMENT``)."""
    if scenario.robot == "sim":
        return make_cell(scenario.cell, seed=scenario.seed)
    from cellguard.robot.bridges import make_bridge

    return make_bridge(scenario.robot, scenario)


def make_clock(robot, realtime: bool):
    """Simulated time for a simulated cell, unless ``realtime``; wall time for a bridge, except one
    in lock-step with a simulated robot behind it (its time moves one period per command)."""
    if hasattr(robot, "step"):
        if not realtime:
            return SimClock(robot)
        return WallClock(robot.dt_ns, step=robot.step, now=lambda: robot.t_ns)
    if getattr(robot, "lockstep", False) and not realtime:
        return LockStepClock(robot)
    return WallClock(robot.dt_ns)


def make_inference(run, realtime: bool):
    """Simulated inference in simulated time; a thread or process worker on wall time."""
    if not run.clock.realtime:
        return SimulatedInference(run.policy, round(1e9 / run.scenario.policy_hz))
    from cellguard.policy.async_inference import AsyncInference

    kind = run.scenario.realtime.inference
    factory = run.policy_factory or partial(policy_in_process, run.scenario.policy, run.cell.name, run.scenario.seed)
    worker = AsyncInference(run.policy, worker=kind, factory=factory if kind == "process" else None,
                            prepare=lambda chunk: run.guard.executor.prepare(chunk))  # the guard of the moment
    return WorkerInference(worker)


def policy_in_process(spec: str, cell_name: str, seed: int):
    """Build policy ``spec`` for the registered cell ``cell_name`` (run in the inference process)."""
    from cellguard.policy.registry import make_policy

    return make_policy(spec, make_cell(cell_name, seed=seed))
