"""A policy whose every answer the guard rejects (not finite, beyond the limits, the wrong shape, its first target
outside the box) is lost as one whose every call fails is: it ran every cycle to its time-out, one chunk_rejected
per request, never moved and exited 0. Rejected chunks among taken ones are not (nor chunks a stop in force held
back: test_runtime_startup's category 0 stop)."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner
from wrapped_policy import WrappedScripted

from cellguard.cli import app
from cellguard.policy.chunk import ActionChunk
from cellguard.robot.registry import make_cell
from cellguard.runtime import Run, run_scenario
from cellguard.scenario import parse_scenario

ARM = "arm-pick-place"
MS = 1_000_000
REJECTED = "policy lost: the guard rejected every chunk, none taken (the last: "


class _Answers(WrappedScripted):
    """The scripted arm policy, whose answers ``bad(call, chunk)`` (calls counted from 1) replaces: a chunk, or an
    exception to raise (a failed call), or None for the scripted chunk itself."""

    source = "test:answers"

    def __init__(self, bad):
        super().__init__()
        self.bad = bad

    def infer(self, observation):
        self.calls += 1
        chunk = self.inner.infer(observation)
        answer = self.bad(self.calls, chunk)
        if isinstance(answer, Exception):
            raise answer
        return chunk if answer is None else answer


def _nan(call, chunk):
    actions = np.array(chunk.actions, dtype=np.float64)
    actions[5, 2] = np.nan
    return ActionChunk(actions, chunk.t_obs_ns, chunk.dt_ns)


def _beyond(call, chunk):
    return ActionChunk(np.asarray(chunk.actions) + 10.0, chunk.t_obs_ns, chunk.dt_ns)


def _shape(call, chunk):
    return ActionChunk(np.zeros((0, 6)), chunk.t_obs_ns, chunk.dt_ns)


def _scenario(**extra):
    return parse_scenario({"cell": ARM, "seed": 3, "acceptance_cycles": 3, "production_cycles": 0,
                           "realtime": {"overrun_budget": 1_000_000}, **extra})


def _run(tmp_path, bad, realtime=False, **extra) -> tuple[float, dict]:
    """The run's summary, and how far the robot was from its start pose when the cycles ended [rad]."""
    scenario = _scenario(**extra)
    run = Run(scenario, realtime=realtime, policy_factory=lambda: _Answers(bad))
    q0, moved = run.cell.read().q, []
    summary = run_scenario(scenario, tmp_path / "out", run=run, on_cycle=lambda _: moved.append(
        float(np.abs(run.link.state.q - q0).max())))
    return max(moved), summary


@pytest.mark.parametrize("bad, why", [(_nan, "non-finite action at step 5, joint elbow)"),
                                      (_beyond, "lies a whole range beyond the limits"),
                                      (_shape, "actions shape (0, 6) does not match (1..1000, 6))")],
                         ids=["nan", "beyond", "shape"])
def test_a_policy_whose_every_chunk_is_rejected_is_lost_and_the_run_stops(tmp_path, bad, why):
    moved, summary = _run(tmp_path, bad)
    assert summary["stopped"].startswith(REJECTED) and why in summary["stopped"]
    kinds = [e["kind"] for e in summary["events"]]
    assert kinds.count("policy_lost") == 1 and 1 < kinds.count("chunk_rejected") < 20
    assert len(summary["cycles"]) == 1 and not summary["cycles"][0]["timed_out"]
    assert moved < 0.01


def test_on_wall_time_too(tmp_path):
    moved, summary = _run(tmp_path, _nan, realtime=True)
    assert summary["stopped"].startswith(REJECTED)
    assert len(summary["cycles"]) == 1 and moved < 0.01


def _straight_up(call, chunk):
    """Every step the arm straight up: the tool at z 0.69 m, over the box's 0.55 m ceiling."""
    up = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.025])
    return ActionChunk(np.tile(up, (len(chunk.actions), 1)), chunk.t_obs_ns, chunk.dt_ns)


def test_a_first_target_outside_the_box_every_time_is_lost_too(tmp_path):
    """A policy whose poses lie outside the workspace box: every first chunk refused, every cycle to its time-out
    before. (A box that leaves out the home pose itself is refused before the run: ``check_home``.)"""
    _, summary = _run(tmp_path, _straight_up)
    assert summary["stopped"].startswith(REJECTED) and "outside the workspace box" in summary["stopped"]
    assert len(summary["cycles"]) == 1


def test_a_policy_that_answers_late_then_only_rejected_chunks_is_lost(tmp_path):
    """Its first answer came after the watchdog: the watchdog weighs the answers until a chunk is taken."""
    _, summary = _run(tmp_path, _nan, guard={"watchdog_s": 0.1},
                        faults=[{"kind": "policy_latency", "at_cycle": 0, "ms": 400}])
    kinds = [e["kind"] for e in summary["events"]]
    assert kinds.index("watchdog_no_first_chunk") < kinds.index("chunk_rejected") < kinds.index("policy_lost")
    assert summary["stopped"].startswith(REJECTED)


def test_a_slow_policys_one_late_rejected_answer_is_no_loss(tmp_path):
    """Its first answer, after the watchdog, rejected; the next one good: the run goes on (one refused answer
    after the watchdog stopped it as lost)."""
    _, summary = _run(tmp_path, lambda call, chunk: _nan(call, chunk) if call == 1 else None,
                      guard={"watchdog_s": 0.1}, faults=[{"kind": "policy_latency", "at_cycle": 0, "ms": 150}])
    kinds = [e["kind"] for e in summary["events"]]
    assert kinds.index("watchdog_no_first_chunk") < kinds.index("chunk_rejected")
    assert "policy_lost" not in kinds and "stopped" not in summary and len(summary["cycles"]) == 3


def test_a_policy_that_answered_its_first_chunk_then_only_rejected_ones_is_lost(tmp_path):
    """The first chunk was approached; no chunk since was taken: the watchdog runs again from the approach."""
    away = make_cell(ARM).read().q + [0.3, 0, 0, 0, 0, 0]

    def answers(call, chunk):
        return ActionChunk(np.tile(away, (25, 1)), chunk.t_obs_ns, 20 * MS) if call == 1 else _nan(call, chunk)

    _, summary = _run(tmp_path, answers)
    kinds = [e["kind"] for e in summary["events"]]
    assert kinds.index("approach_done") < kinds.index("chunk_rejected") < kinds.index("policy_lost")
    assert summary["stopped"].startswith(REJECTED)


def test_failed_calls_and_rejected_chunks_together_are_named_both(tmp_path):
    _, summary = _run(tmp_path, lambda call, chunk: RuntimeError("server error") if call % 2 else _nan(call, chunk))
    assert summary["stopped"] == ("policy lost: every call failed or its chunk was rejected, none taken (the last "
                                  "failure: RuntimeError: server error; the last rejection: non-finite action at step "
                                  "5, joint elbow)")


def test_rejected_chunks_among_taken_ones_keep_the_run_going(tmp_path):
    """Its first two answers and every third since rejected: it answers, the run runs every cycle."""
    _, summary = _run(tmp_path, lambda call, chunk: _nan(call, chunk) if call <= 2 or call % 3 == 0 else None)
    kinds = [e["kind"] for e in summary["events"]]
    assert "stopped" not in summary and "policy_lost" not in kinds
    assert kinds.count("chunk_rejected") > 20 and "watchdog_no_first_chunk" not in kinds
    assert [c["success"] for c in summary["cycles"]] == [True] * 3


def test_the_command_exits_1_naming_the_lost_policy(tmp_path):
    q = make_cell(ARM).read().q
    actions = np.tile(q, (1, 10, 1))
    actions[0, 5, 2] = np.nan
    np.savez(tmp_path / "nan.npz", t=np.array([0.0]), actions=actions, dt=np.array(0.05))
    (tmp_path / "s.yaml").write_text(f"cell: {ARM}\nacceptance_cycles: 2\nproduction_cycles: 0\n"
                                     f"policy: replay:{tmp_path / 'nan.npz'}\n")
    result = CliRunner().invoke(app, ["run", str(tmp_path / "s.yaml"), "--out", str(tmp_path / "out")])
    assert result.exit_code == 1, result.output
    last = result.stderr.splitlines()[-1]
    assert last.startswith(f"error: the cell was stopped (policy_lost): {REJECTED}non-finite action"), result.stderr
