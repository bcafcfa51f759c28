"""A policy that answers no more (its process ended, a call hung, a warm-up that never returns) ends the run with
one named event, and a start-up refusal is in the record."""

from __future__ import annotations

import os
import signal
import threading
from functools import partial

import pytest
from wrapped_policy import WrappedScripted

from cellguard.record.reader import open_record
from cellguard.runtime import Run, loop, run_scenario
from cellguard.runtime.startup import StartupRefused
from cellguard.scenario import parse_scenario

ARM = "arm-pick-place"


class _Stalls(WrappedScripted):
    """The scripted arm policy, whose call number ``at`` (the warm-up is the first) ends its process (``die``)
    or waits to be released (5 s at most: a test never hangs), after sending SIGTERM if ``signals``."""

    source = "test:stalls"

    def __init__(self, at: int, die: bool = False, signals: bool = False):
        super().__init__()
        self.at, self.die, self.signals = at, die, signals
        self.answered, self.release = False, threading.Event()

    def infer(self, observation):
        self.calls += 1
        if self.calls == self.at:
            if self.die:
                os._exit(3)
            if self.signals:
                os.kill(os.getpid(), signal.SIGTERM)
            self.release.wait(5.0)
            self.answered = True
        return self.inner.infer(observation)


def _scenario(**realtime):
    return parse_scenario({"cell": ARM, "acceptance_cycles": 1, "production_cycles": 1,
                           "cycle": {"source": "time", "seconds": 2.0},
                           "realtime": {"overrun_budget": 1_000_000, **realtime}})


def _run(scenario, out, **stalls) -> tuple[dict, bool]:
    """Run ``scenario`` with a ``_Stalls`` policy; the summary, and whether the stalled call had answered when
    the run returned (released then)."""
    run = Run(scenario, realtime=True, policy_factory=partial(_Stalls, **stalls))
    try:
        return run_scenario(scenario, out, run=run), run.policy.answered
    finally:
        run.policy.release.set()


def test_a_policy_process_that_ends_mid_run_stops_the_run_with_one_event(tmp_path):
    """Every later cycle waited out its time-out, each request failed (an inference_failed event every 50 ms),
    and the run ended with nothing stopped (exit 0)."""
    summary, _ = _run(_scenario(inference="process"), tmp_path / "out", at=4, die=True)
    kinds = [e["kind"] for e in summary["events"]]
    assert summary["stopped"] == "policy lost: policy process ended (exit code 3)"
    assert kinds.count("policy_lost") == 1 and "inference_failed" not in kinds
    assert next(e for e in summary["events"] if e["kind"] == "policy_lost")["category"] == 2  # the watchdog's
    assert len(summary["cycles"]) == 1 and "retreat_done" in kinds  # stopped, held, then home


def test_a_call_that_hangs_far_past_the_watchdog_stops_the_run(tmp_path, monkeypatch):
    """The watchdog held the robot and the run went on, every cycle timed out, with nothing stopped."""
    monkeypatch.setattr(loop, "HUNG_WATCHDOGS", 2, raising=False)  # 0.6 s with the default 0.3 s watchdog
    summary, answered = _run(_scenario(), tmp_path / "out", at=4)
    kinds = [e["kind"] for e in summary["events"]]
    # 0.6 s, or two of the scripted program's 0.5 s chunks once one has come
    assert summary["stopped"] == "policy lost: the policy's call has not answered in 1.0 s"
    assert kinds.count("policy_lost") == 1 and kinds.index("watchdog_stop") < kinds.index("policy_lost")
    assert len(summary["cycles"]) == 1 and not answered  # never waited for, not even at close


class _Slow(_Stalls):
    """The scripted arm policy, every call taking ``seconds`` (its warm-up too)."""

    def __init__(self, seconds: float):
        super().__init__(at=0)
        self.seconds = seconds

    def infer(self, observation):
        threading.Event().wait(self.seconds)
        return super().infer(observation)


def test_a_slow_policy_that_answers_is_not_lost(tmp_path, monkeypatch):
    """A live policy slower than the watchdog bound (here 0.15 s) but inside its chunks (0.17 s a call for 0.5 s
    chunks: asked again 260 ms in, the next chunk 431 ms after this one's observation, which start-up accepts) was
    stopped as lost at its first timed call. (0.25 s calls ran every chunk out: start-up refuses them.)"""
    monkeypatch.setattr(loop, "HUNG_WATCHDOGS", 0.5, raising=False)
    scenario = parse_scenario({"cell": ARM, "acceptance_cycles": 1, "production_cycles": 1,
                               "cycle": {"source": "time", "seconds": 2.0},
                               "realtime": {"overrun_budget": 1_000_000}})
    run = Run(scenario, realtime=True, policy_factory=partial(_Slow, 0.17))
    summary = run_scenario(scenario, tmp_path / "out", run=run)
    assert "stopped" not in summary and len(summary["cycles"]) == 2
    assert "policy_lost" not in [e["kind"] for e in summary["events"]]


def test_a_policy_hung_in_its_warm_up_refuses_the_start_with_the_refusal_in_the_record(tmp_path, monkeypatch):
    """The warm-up ran the policy on the main thread, waited for it forever and left no trace in the record."""
    monkeypatch.setattr(loop, "WARM_UP_TIMEOUT_S", 0.3, raising=False)
    run = Run(_scenario(), realtime=True, policy_factory=partial(_Stalls, at=1))
    try:
        with pytest.raises(StartupRefused, match=r"^start-up: the policy's first call has not answered in 0.3 s; "
                                                 r"not moving$"):
            run_scenario(run.scenario, tmp_path / "out", run=run)
        assert not run.policy.answered
    finally:
        run.policy.release.set()
    with open_record(tmp_path / "out") as rec:
        assert [e.kind for e in rec.events()] == ["startup_refused"]
    assert run.recording.finished


def test_a_stop_signal_during_the_warm_up_ends_the_run_without_waiting_for_the_policy(tmp_path):
    """SIGTERM during a hung warm-up was only counted: the main thread waited in the policy's call."""
    summary, answered = _run(_scenario(), tmp_path / "out", at=1, signals=True)
    assert summary["stopped"] == "operator stop (SIGTERM)" and not answered
    stop = next(e for e in summary["events"] if e["kind"] == "operator_stop")
    assert stop["reason"] == "SIGTERM: the operator asked a stop during the policy's warm-up"
