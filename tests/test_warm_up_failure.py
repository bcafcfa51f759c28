"""On wall time, a policy its inference process cannot build is refused before anything moves (every call answered
"policy could not be built", a watchdog stop, exit 0, never having moved); a policy whose first calls fail and that
then answers (a cold server) is not refused: the run moves once it answers."""

from __future__ import annotations

import multiprocessing

import numpy as np
import pytest

from cellguard.policy.chunk import ActionChunk
from cellguard.runtime import Run, run_scenario
from cellguard.runtime.startup import StartupRefused
from cellguard.scenario import parse_scenario

MS = 1_000_000


class _Still:
    """Holds the pose it is shown, in 25 steps of 20 ms; its first ``failures`` calls raise (a cold server)."""

    source = "test:still"

    def __init__(self, failures: int = 0):
        self.failures = failures

    def reset(self):
        pass

    def content_hash(self):
        return "0" * 64

    def infer(self, observation):
        if self.failures > 0:
            self.failures -= 1
            raise TimeoutError("no answer in 1 s")
        return ActionChunk(np.tile(observation.q, (25, 1)), observation.t_ns, 20 * MS)


def _built_here_only() -> _Still:
    """The policy, but not in a child process (a file the inference process cannot read)."""
    if multiprocessing.parent_process() is not None:
        raise FileNotFoundError("policy.onnx: no such file here")
    return _Still()


def _scenario(inference: str):
    return parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 0,
                           "cycle": {"source": "time", "seconds": 1.0},
                           "realtime": {"inference": inference, "overrun_budget": 1_000_000}})


def test_a_policy_its_process_cannot_build_is_refused_before_the_robot_moves():
    run = Run(_scenario("process"), realtime=True, policy_factory=_built_here_only)
    q0 = run.cell.read().q
    try:
        with pytest.raises(StartupRefused, match=r"^start-up: policy could not be built: FileNotFoundError: "
                                                 r"policy.onnx: no such file here; not moving$"):
            run.cycle()
    finally:
        run.close()
    kinds = [e.kind for e in run.events]
    assert kinds[-1] == "startup_refused" and "inference_failed" not in kinds
    assert np.abs(run.cell.read().q - q0).max() < 1e-3


def test_a_policy_whose_first_calls_fail_moves_once_it_answers():
    run = Run(_scenario("thread"), realtime=True, policy_factory=lambda: _Still(failures=2))
    try:
        run.cycle()
    finally:
        run.close()
    kinds = [e.kind for e in run.events]
    assert "startup_refused" not in kinds and kinds.count("inference_failed") >= 1
    assert run.guard.executor.last_chunk_ns is not None  # it answered, and its chunk was played


class _Failing(_Still):
    """A policy whose every call raises (a server answering 500 to everything)."""

    def infer(self, observation):
        raise RuntimeError("the policy server answered 500")


@pytest.mark.parametrize("realtime", [False, True], ids=["simulated", "wall"])
def test_a_policy_that_never_answers_stops_the_run_as_lost(tmp_path, realtime):
    """Every call failed: the run went on asking it, one inference_failed per request, every cycle failed and it
    ended clean (exit 0), never having moved. A cold one that answers within the watchdog is not lost (above)."""
    scenario = parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 3, "production_cycles": 0,
                               "realtime": {"overrun_budget": 1_000_000}})
    run = Run(scenario, realtime=realtime, policy_factory=_Failing)
    summary = run_scenario(scenario, tmp_path / "out", run=run)
    assert summary["stopped"] == ("policy lost: every call failed before the first chunk (the last: RuntimeError: "
                                  "the policy server answered 500)")
    assert len(summary["cycles"]) == 1
