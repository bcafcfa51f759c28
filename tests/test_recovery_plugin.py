"""A recovery behaviour written outside the project (a plugin) that fails to plan, or plans something broken.

An exception from a behaviour's ``plan()`` other than the arm's reach (ValueError), or a result that was not
a Plan, left the servo loop as a traceback: exit 1, no summary.json, nothing in the record saying why the run
ended. A plan with a time that is not finite ran, and its attempt vanished from the diagnosis, as did every
attempt of a behaviour whose name held anything outside [a-z_] (``regrasp2``): the diagnosis read attempts back
from the words of their events (it reads each cycle's ``recovery_log`` now). Each is an unplannable attempt now:
logged naming the behaviour and the error, then home, and the cycle fails. These tests stand the plugin's
``plan()`` in for retry_grasp's (``test_recovery_discovery.py`` adds a behaviour module of its own).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.diagnose.recovery import attempts_of
from cellguard.robot.recovery import Plan
from cellguard.robot.recovery.outcome import RecoveryOutcome
from cellguard.robot.recovery.retry_grasp import RetryGrasp
from cellguard.runtime import Run
from cellguard.scenario import parse_scenario

SCENARIO = {"cell": "arm-pick-place", "acceptance_cycles": 0, "production_cycles": 1,
            "faults": [{"kind": "intermittent_slip", "rate": 1.0, "dx_mm": -5.0}],
            "recovery": {"behaviours": [{"do": "retry_grasp", "trigger": "grasp_missed"}]}}
HOME = "no recovery left (retry_grasp could not make a plan): home, the cycle fails"


def _boom(self, cell, q, attempt, origin):
    raise RuntimeError("plugin recovery blew up")


def _dict(self, cell, q, attempt, origin):
    return {"arm": q}


def _nan_close(self, cell, q, attempt, origin):
    return Plan(np.array([0.0, 1.0]), np.stack([q[:-1], q[:-1]]), np.array([0.0, 1.0]), np.array([q[-1]] * 2),
                q[:-1], float("nan"))


def _narrow(self, cell, q, attempt, origin):
    return Plan(np.array([0.0, 1.0]), np.zeros((2, 2)), np.array([0.0, 1.0]), np.array([q[-1]] * 2))


def _scalar_contact(self, cell, q, attempt, origin):
    return Plan(np.array([0.0, 1.0]), np.stack([q[:-1], q[:-1]]), np.array([0.0, 1.0]), np.array([q[-1]] * 2),
                np.float64(0.3), 0.5)


def _lists(self, cell, q, attempt, origin):
    """Tracks as Python lists: sampled, they ended the run in a TypeError."""
    return Plan([0.0, 1.0], [list(q[:-1]), list(q[:-1])], [0.0, 1.0], [q[-1], q[-1]])


def _empty(self, cell, q, attempt, origin):
    return Plan(np.zeros(0), np.zeros((0, len(q) - 1)), np.zeros(0), np.zeros(0))


@pytest.mark.parametrize(("plan", "error"), [
    (_boom, "RuntimeError: plugin recovery blew up"),
    (_empty, "PlanError: its arm_t is not one or more times in order"),
    (_dict, "PlanError: plan() returned a dict, not a Plan"),
    (_nan_close, "PlanError: its close_t is not finite"),
    (_narrow, "PlanError: its arm_q has shape (2, 2), for an arm of 5 joints"),
    (_scalar_contact, "PlanError: its contact_q has shape (), for an arm of 5 joints"),
])
def test_a_behaviour_that_cannot_plan_is_logged_and_the_cell_goes_home(monkeypatch, plan, error):
    monkeypatch.setattr(RetryGrasp, "plan", plan)
    run = Run(parse_scenario(SCENARIO))
    outcome = run.cycle()
    assert not outcome["success"]
    ends = [e.reason for e in run.events if e.kind == "recovery_end"]
    assert ends == [f"retry_grasp: attempt 1 cannot be planned ({error})", HOME]
    assert not any(e.kind == "recovery_start" for e in run.events)
    home = np.asarray(run.cell.q_home)
    assert np.abs(run.guard.reference[:-1] - home[:-1]).max() < 1e-3  # the next cycle starts at home


def test_a_plan_of_lists_is_followed_as_arrays(monkeypatch):
    """Checked with np.shape and len, a plan of lists passed and ended the run when the loop sampled it."""
    monkeypatch.setattr(RetryGrasp, "plan", _lists)
    run = Run(parse_scenario(SCENARIO))
    run.cycle()
    assert any(e.kind == "recovery_start" for e in run.events)
    assert not any("cannot be planned" in e.reason for e in run.events if e.kind == "recovery_end")


def test_a_run_whose_behaviour_blows_up_ends_whole_with_its_summary(monkeypatch, tmp_path):
    monkeypatch.setattr(RetryGrasp, "plan", _boom)
    scenario = tmp_path / "s.yaml"
    scenario.write_text(json.dumps({**SCENARIO, "production_cycles": 2}))
    result = CliRunner().invoke(app, ["run", str(scenario), "--out", str(tmp_path / "out")])
    assert result.exit_code == 0, result.output
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["phases"]["production"] == {"cycles": 2, "success_rate": 0.0}
    assert sum(HOME == e["reason"] for e in summary["events"]) == 2


@pytest.mark.parametrize("name", ["regrasp2", "retry_grasp_v2", "ReGrasp", "re-grasp", "retry: attempt 9 after"])
@pytest.mark.parametrize("close", [1.8, None])
def test_a_behaviour_with_any_name_reads_back_from_its_log(name, close):
    done = RecoveryOutcome(name, "grasp_missed", 2, "failed", 3.25, 1.5 if close else None, close)
    assert attempts_of([{"cycle": 4, "features": {}, "outcome": {"recovery_log": [done.to_dict()]}}]) == [(4, done)]


@pytest.mark.parametrize(("field", "value"), [("close_t", float("nan")), ("close_t", float("inf")),
                                              ("hold_s", float("nan")), ("arm_q", np.array([[0.0], [np.nan]])),
                                              ("grip_t", np.array([0.0, np.inf])), ("contact_q", np.array([np.nan]))])
def test_a_plan_that_is_not_finite_is_refused_when_made(field, value):
    from cellguard.robot.recovery.base import PlanError

    fields = {"arm_t": np.array([0.0, 1.0]), "arm_q": np.array([[0.0], [1.0]]), "grip_t": np.array([0.0, 1.0]),
              "grip_q": np.array([0.02, 0.0]), "contact_q": np.array([1.0]), "close_t": 0.5, field: value}
    with pytest.raises(PlanError, match=f"its {field} is not finite"):
        Plan(**fields)


@pytest.mark.parametrize(("arm_q", "grip_q", "message"), [
    (np.array([[0.0], [1.0], [2.0]]), np.array([0.02, 0.0]), "its arm_q is not 2 poses, one per arm_t"),
    (np.array([0.0, 1.0]), np.array([0.02, 0.0]), "its arm_q is not 2 poses, one per arm_t"),
    (np.array([[0.0], [1.0]]), np.array([0.02]), "its grip_q is not 2 values, one per grip_t"),
])
def test_a_plan_whose_tracks_do_not_match_their_times_is_refused(arm_q, grip_q, message):
    from cellguard.robot.recovery.base import PlanError

    with pytest.raises(PlanError, match=message):
        Plan(np.array([0.0, 1.0]), arm_q, np.array([0.0, 1.0]), grip_q)


@pytest.mark.parametrize(("arm_t", "grip_t", "message"), [
    (np.array([1.0, 0.0]), np.array([0.0, 1.0]), "its arm_t is not one or more times in order"),
    (np.array([[0.0, 1.0]]), np.array([0.0, 1.0]), "its arm_t is not one or more times in order"),
    (np.array([0.0, 1.0]), np.array(0.0), "its grip_t is not one or more times in order"),
])
def test_a_plan_whose_times_are_not_a_track_is_refused(arm_t, grip_t, message):
    from cellguard.robot.recovery.base import PlanError

    with pytest.raises(PlanError, match=message):
        Plan(arm_t, np.array([[0.0], [1.0]]), grip_t, np.array([0.02, 0.0]))
