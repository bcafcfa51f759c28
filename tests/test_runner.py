"""The tick loop survives a policy that fails: the failure is an event and the watchdog stops the cell."""

from __future__ import annotations

import numpy as np

from cellguard.runtime import Run
from cellguard.scenario import parse_scenario


class _FailsAfter:
    """Wraps a working policy; every call after ``calls`` raises, like a lost inference server."""

    def __init__(self, policy, calls: int):
        self._policy, self._left = policy, calls
        self.source = "test:fails-after"

    def reset(self) -> None:
        self._policy.reset()

    def content_hash(self) -> str:
        return self._policy.content_hash()

    def infer(self, observation):
        self._left -= 1
        if self._left < 0:
            raise ConnectionError("inference server went away")
        return self._policy.infer(observation)


def test_a_failing_policy_becomes_events_and_a_watchdog_stop():
    run = Run(parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 0}))
    run.policy = _FailsAfter(run.policy, calls=20)  # one second of chunks, then nothing
    outcome = run.cycle()
    kinds = [e.kind for e in run.events]
    assert "inference_failed" in kinds and "watchdog_stop" in kinds
    assert kinds.index("watchdog_stop") > kinds.index("inference_failed")
    assert "ConnectionError: inference server went away" in next(e.reason for e in run.events
                                                                 if e.kind == "inference_failed")
    assert not outcome["success"]
    assert np.isfinite(run.ticks.rows("setpoint")).all()
    assert abs(run.ticks.rows("qd")[-1]).max() < 0.05  # the arm came to rest


def test_the_watchdog_arms_at_start_when_no_chunk_ever_comes():
    run = Run(parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 0}))
    run.policy = _FailsAfter(run.policy, calls=0)  # not a single chunk
    run.cycle()
    first = next(e for e in run.events if e.kind == "watchdog_no_first_chunk")
    assert first.category == 2
    assert first.t_ns <= 0.3e9 + 2 * run.cell.dt_ns  # the guard's watchdog time after the start
    assert "protective_stop" in [e.kind for e in run.events]
    assert abs(run.ticks.rows("qd")[-1]).max() < 0.05  # nothing moved on


def test_the_loop_closes_the_policy_at_the_end_of_the_run(tmp_path):
    from cellguard.policy.registry import make_policy
    from cellguard.robot.registry import make_cell
    from cellguard.runtime import run_scenario

    closed = []

    class Closing(_FailsAfter):
        def close(self):
            closed.append(True)

    sc = parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 0})
    run_scenario(sc, tmp_path / "out",
                 policy_factory=lambda: Closing(make_policy("scripted", make_cell("arm-pick-place")), calls=10**6))
    assert closed == [True]
