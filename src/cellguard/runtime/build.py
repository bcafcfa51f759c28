"""What a scenario names, built for the loop: the robot, the clock, the inference worker."""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

from cellguard.embodiment import Profile
from cellguard.embodiment.profile import SOFT_MARGIN, calibrated_profile
from cellguard.errors import ScenarioError
from cellguard.robot.registry import make_cell
from cellguard.robot.state import Observation
from cellguard.runtime.clock import LockStepClock, SimClock, WallClock
from cellguard.runtime.inference import NOMINAL_INFERENCE_S, SimulatedInference, WorkerInference


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


def first_chunk_ns(clock) -> int | None:
    """How long after a cycle's start its first chunk is taken at the soonest, where the scenario says it [ns]:
    simulated inference answers the request at the cycle's first tick ``NOMINAL_INFERENCE_S`` later (a fault only
    adds), taken at the first tick from then; None on wall time (the policy's own latency, measured)."""
    if clock.realtime:
        return None
    return -(-round(NOMINAL_INFERENCE_S * 1e9) // clock.period_ns) * clock.period_ns


def make_inference(run):
    """Simulated inference in simulated time; a thread or process worker on wall time (both at most at the
    scenario's ``policy_hz``)."""
    if not run.clock.realtime:
        return SimulatedInference(run.policy, round(1e9 / run.scenario.policy_hz))
    from cellguard.policy.async_inference import AsyncInference

    kind = run.scenario.realtime.inference
    factory = (run.policy_factory or _policy_again(run)) if kind == "process" else None
    worker = AsyncInference(run.policy, worker=kind, factory=factory,
                            prepare=lambda chunk: run.guard.executor.prepare(chunk))  # the guard of the moment
    return WorkerInference(worker, round(1e9 / run.scenario.policy_hz))


def _policy_again(run):
    """How the inference process builds the run's policy again: a simulated cell's from the cell built anew by its
    registered name (a plugin's program reads what it reads of its cell); a bridge's from what the run's was built
    from, as the run's process saw the bridge (its name need not be a cell's, its servo rate and seed may differ from
    a cell built by that name; its link is the run's alone)."""
    if run.simulated:
        return partial(policy_in_process, run.scenario.policy, run.cell.name, run.scenario.seed,
                       run.scenario.guard.soft_margin)
    from cellguard.policy.registry import make_policy

    return partial(make_policy, run.scenario.policy, BridgeSeen.of(run.cell),
                   soft_margin=run.scenario.guard.soft_margin)


def policy_in_process(spec: str, cell_name: str, seed: int, soft_margin: float = SOFT_MARGIN):
    """Build policy ``spec`` for the registered cell ``cell_name`` (run in the inference process), its IK inside the
    guard's ``soft_margin``."""
    from cellguard.policy.registry import make_policy

    return make_policy(spec, make_cell(cell_name, seed=seed), soft_margin=soft_margin)


@dataclass(frozen=True)
class BridgeSeen:
    """What building a policy reads of a bridge (``make_policy``: its ``Robot`` data, context, an observation, its
    model if it has one), copied in the run's process so that it pickles into the inference process."""

    name: str
    profile: Profile
    dt_ns: int
    manifest: dict  # its context()
    observation: Observation
    model: object | None = None

    @classmethod
    def of(cls, robot) -> BridgeSeen:
        return cls(robot.name, robot.profile, robot.dt_ns, robot.context(), robot.observe(),
                   getattr(robot, "model", None))

    def context(self) -> dict:
        return self.manifest

    def observe(self) -> Observation:
        return self.observation
