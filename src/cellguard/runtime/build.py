"""What a scenario names, built for the loop: the robot, the clock, the inference worker."""

from __future__ import annotations

from functools import partial

from cellguard.embodiment.profile import calibrated_profile
from cellguard.errors import ScenarioError
from cellguard.robot.registry import make_cell
from cellguard.runtime.clock import LockStepClock, SimClock, WallClock
from cellguard.runtime.inference import SimulatedInference, WorkerInference


def make_robot(scenario):
    """``robot: sim`` is the scenario's simulated cell; anything else a bridge (``SCHEME:ARGUMENT``). With a
    ``calibration`` (a profile ``identify --write`` wrote) the robot takes that profile in place of its own, and
    ``profile_file``, the file read, resolved now: the scenario's path is relative to this working folder (a replay
    from another folder found no file there), and a link repointed later is not the file this run read."""
    if scenario.robot == "sim":
        robot = make_cell(scenario.cell, seed=scenario.seed)
    else:
        from cellguard.robot.bridges import make_bridge

        robot = make_bridge(scenario.robot, scenario)
    if scenario.calibration is not None:
        if not hasattr(robot, "model"):
            raise ScenarioError(f"calibration: robot {scenario.robot!r} has no MuJoCo model to check the profile "
                                "against; give a bridge its calibrated profile with its embodiment= option")
        robot.profile = calibrated_profile(robot.model, robot.profile, scenario.calibration)
        robot.profile_file = scenario.calibration.resolve()
    return robot


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


def make_inference(run):
    """Simulated inference in simulated time; a thread or process worker on wall time (both at most at the
    scenario's ``policy_hz``)."""
    if not run.clock.realtime:
        return SimulatedInference(run.policy, round(1e9 / run.scenario.policy_hz))
    from cellguard.policy.async_inference import AsyncInference

    kind = run.scenario.realtime.inference
    factory = run.policy_factory or partial(policy_in_process, run.scenario.policy, run.cell.name, run.scenario.seed)
    worker = AsyncInference(run.policy, worker=kind, factory=factory if kind == "process" else None,
                            prepare=lambda chunk: run.guard.executor.prepare(chunk))  # the guard of the moment
    return WorkerInference(worker, round(1e9 / run.scenario.policy_hz))


def policy_in_process(spec: str, cell_name: str, seed: int):
    """Build policy ``spec`` for the registered cell ``cell_name`` (run in the inference process)."""
    from cellguard.policy.registry import make_policy

    return make_policy(spec, make_cell(cell_name, seed=seed))
