"""On wall time a policy whose first call (the warm-up, before anything moves) fails is refused in one line: the
run went on asking it, logged a failure per request, stopped on its watchdog and exited 0, never having moved."""

from __future__ import annotations

import numpy as np
import pytest

from cellguard.runtime import Run
from cellguard.runtime.startup import StartupRefused
from cellguard.scenario import parse_scenario


class _Failing:
    """A policy whose every call raises, as one that cannot be built in its process or a server answering 500."""

    source = "test:failing"

    def reset(self):
        pass

    def content_hash(self):
        return "0" * 64

    def infer(self, observation):
        raise RuntimeError("the policy server answered 500")


@pytest.mark.parametrize("inference", ["thread", "process"])
def test_a_policy_whose_first_call_fails_is_refused_before_the_robot_moves(inference):
    scenario = parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 0,
                               "cycle": {"source": "time", "seconds": 1.0},
                               "realtime": {"inference": inference, "overrun_budget": 1_000_000}})
    run = Run(scenario, realtime=True, policy_factory=_Failing)
    q0 = run.cell.read().q
    try:
        with pytest.raises(StartupRefused, match=r"^start-up: the policy's first call failed: .*the policy server "
                                                 r"answered 500; not moving$"):
            run.cycle()
    finally:
        run.close()
    kinds = [e.kind for e in run.events]
    assert kinds[-1] == "startup_refused" and "inference_failed" not in kinds
    assert np.abs(run.cell.read().q - q0).max() < 1e-3
