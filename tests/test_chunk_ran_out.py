"""A chunk that ends before the next arrives: the reference held its last step and stopped dead in one tick, and
only the guard's limit interventions said anything. The executor says so, once per run-out, at the next arrival."""

from __future__ import annotations

import numpy as np

from cellguard.control.executor import Executor
from cellguard.diagnose.diagnosis import ROUTINE_EVENTS
from cellguard.policy.chunk import ActionChunk
from cellguard.robot.registry import make_cell
from cellguard.runtime import Run
from cellguard.scenario import parse_scenario

MS = 1_000_000


def _ramp(t_obs_ns: int, h: int = 5) -> ActionChunk:
    """``h`` steps of 20 ms moving the arm's joints 0.01 rad a step along one ramp in time; the gripper held."""
    steps = t_obs_ns / (20 * MS) + np.arange(1, h + 1)[:, None]
    return ActionChunk(np.where(np.arange(6) < 5, 0.01 * steps, 0.02), t_obs_ns, 20 * MS)


def _ran_out(events) -> list:
    return [e for e in events if e.kind == "chunk_ran_out"]


def test_a_chunk_that_ends_before_the_next_arrives_is_told_once_with_how_long_it_held():
    executor = Executor(make_cell("arm-pick-place").profile, _ramp(-20 * MS).actions[0], MS)
    assert not _ran_out(executor.push(_ramp(0), MS))  # from the hold before the first chunk: nothing ran out
    for t in range(MS, 150 * MS, MS):  # the chunk's last step is at 100 ms; 50 ticks of holding it
        executor.reference(t)
    events = executor.push(_ramp(100 * MS), 150 * MS)
    assert [e.reason for e in _ran_out(events)] == [
        "the chunk in use ran out 50 ms before this one arrived: its last step was held meanwhile"]
    assert events[0].t_ns == 150 * MS


def test_a_chunk_that_arrives_in_time_tells_nothing():
    executor = Executor(make_cell("arm-pick-place").profile, _ramp(-20 * MS).actions[0], MS)
    executor.push(_ramp(0), MS)
    for t in range(MS, 90 * MS, MS):
        executor.reference(t)
    assert not _ran_out(executor.push(_ramp(60 * MS), 90 * MS))


def test_a_run_whose_chunks_run_out_says_so_once_per_chunk():
    """280 ms latency on the scripted arm's 500 ms chunks: each chunk ends before the next arrives."""
    run = Run(parse_scenario({"cell": "arm-pick-place", "seed": 3, "acceptance_cycles": 1, "production_cycles": 0,
                              "cycle": {"source": "time", "seconds": 2.0},
                              "faults": [{"kind": "policy_latency", "at_cycle": 0, "ms": 280}]}))
    run.cycle()
    ran_out = _ran_out(run.events)
    assert 3 <= len(ran_out) <= 2.0 / 0.280  # one a run-out (at an arrival, one a latency at most), not one a tick
    assert all(e.reason.startswith("the chunk in use ran out ") for e in ran_out)


def test_a_chunk_that_ran_out_is_no_intervention_of_its_own():
    """The guard's braking after it is the intervention: counted too, the event doubled interventions_per_hour (a
    release gate) and the diagnosis' interventions feature for the same motion."""
    run = Run(parse_scenario({"cell": "arm-pick-place", "seed": 3, "acceptance_cycles": 1, "production_cycles": 0,
                              "cycle": {"source": "time", "seconds": 2.0},
                              "faults": [{"kind": "policy_latency", "at_cycle": 0, "ms": 280}]}))
    outcome = run.cycle()
    assert _ran_out(run.events)
    assert outcome["features"]["interventions"] == sum(e.kind not in ROUTINE_EVENTS and e.kind != "chunk_ran_out"
                                                       for e in run.events)
