"""Recoveries: scenario validation, plans, the runner in a simulated cell, and the record of each attempt."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import ScenarioError
from cellguard.robot.recovery import RECOVERIES, Plan
from cellguard.robot.recovery.outcome import OUTCOMES, RecoveryOutcome
from cellguard.runtime import Run
from cellguard.scenario import parse_scenario

SLIP = {"kind": "intermittent_slip", "rate": 1.0, "dx_mm": -5.0}  # every cycle: the grasp misses
RETRY = {"behaviours": [{"do": "retry_grasp", "trigger": "grasp_missed", "attempts": 2, "then": "operator"},
                        {"do": "operator", "hold_s": 0.3}]}


def _scenario(**patch):
    return parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 0, "production_cycles": 1, **patch})


@pytest.mark.parametrize(("recovery", "message"), [
    ({"behaviours": [{"do": "pray"}]}, "recovery.behaviours[0]: unknown recovery; known: 'retry_grasp'"),
    ({"behaviours": [{"do": "retry_grasp", "then": "back_off"}, {"do": "back_off", "then": "retry_grasp"}]},
     "the escalations loop (retry_grasp -> back_off -> retry_grasp) without a limit; set recovery.max_per_cycle"),
    ({"behaviours": [{"do": "rehome", "then": "rehome"}]}, "loop (rehome -> rehome) without a limit"),
    ({"behaviours": [{"do": "retry_grasp", "then": "operator"}]}, "'operator' is not a declared behaviour"),
    ({"behaviours": [{"do": "rehome"}, {"do": "rehome"}]}, "'rehome' is declared twice"),
    ({"behaviours": [{"do": "retry_grasp", "trigger": "grasp_missed"}, {"do": "back_off", "trigger": "grasp_missed"}]},
     "behaviours[1].trigger: 'grasp_missed' already starts 'retry_grasp'; escalate with then: instead"),
    ({"behaviours": [{"do": "retry_grasp", "trigger": "grasp_missed"}, {"do": "rehome"}]},
     "behaviours[1]: 'rehome' has no trigger and no triggered behaviour escalates to it, so it never runs"),
    ({"behaviours": [{"do": "retry_grasp", "trigger": "grasp_missed"}, {"do": "operator", "then": "rehome"},
                     {"do": "rehome", "then": "operator"}], "max_per_cycle": 3},
     "behaviours[1]: 'operator' has no trigger and no triggered behaviour escalates to it"),
    ({"behaviours": [{"do": "retry_grasp", "attempts": 0}]}, "behaviours[0].attempts: Input should be greater"),
    ({"behaviours": [{"do": "retry_grasp", "search_mm": 1e3}]}, "behaviours[0].search_mm"),
    ({"behaviours": []}, "recovery.behaviours: List should have at least 1 item"),
])
def test_bad_recovery_names_the_key(recovery, message):
    with pytest.raises(ScenarioError) as info:
        _scenario(recovery=recovery)
    assert message in str(info.value) and "\n" not in str(info.value)


def test_a_loop_with_a_limit_is_allowed():
    s = _scenario(recovery={"max_per_cycle": 4, "behaviours": [
        {"do": "retry_grasp", "trigger": "grasp_missed", "then": "back_off"},
        {"do": "back_off", "then": "retry_grasp"}]})
    assert s.recovery.max_per_cycle == 4


def test_a_cell_that_cannot_run_a_recovery_is_refused():
    with pytest.raises(ScenarioError, match=r"recovery.behaviours\[0\].do: 'retry_grasp' cannot run on "
                                            r"'quadruped-turns'"):
        Run(parse_scenario({"cell": "quadruped-turns", "production_cycles": 1,
                            "recovery": {"behaviours": [{"do": "retry_grasp", "trigger": "grasp_missed"}]}}))
    with pytest.raises(ScenarioError, match=r"behaviours\[0\].trigger: 'arm-pick-place' does not report 'smoke'"):
        Run(_scenario(recovery={"behaviours": [{"do": "rehome", "trigger": "smoke"}]}))


@pytest.mark.parametrize(("body", "needle"), [
    ("recovery:\n  behaviours:\n    - {do: teleport}\n", "unknown recovery"),
    ("recovery:\n  behaviours:\n    - {do: rehome, then: rehome}\n", "without a limit"),
])
def test_bad_recovery_on_the_command_line_is_one_line_and_exit_2(tmp_path, body, needle):
    scenario = tmp_path / "s.yaml"
    scenario.write_text("cell: arm-pick-place\nproduction_cycles: 1\n" + body)
    result = CliRunner().invoke(app, ["run", str(scenario), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2 and result.stderr.strip().count("\n") == 0 and needle in result.stderr
    assert not (tmp_path / "out").exists()


def test_a_cell_that_cannot_run_it_on_the_command_line_is_one_line_and_exit_2(tmp_path):
    scenario = tmp_path / "s.yaml"
    scenario.write_text("cell: quadruped-turns\nproduction_cycles: 1\nrecovery:\n  behaviours:\n"
                        "    - {do: reregister_datum, trigger: grasp_missed}\n")
    result = CliRunner().invoke(app, ["run", str(scenario), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2 and result.stderr.strip().count("\n") == 0 and "cannot run" in result.stderr


MS = st.floats(0, 100).map(lambda t: round(t, 3))  # [s] the runner logs its times to the millisecond


@given(st.sampled_from(sorted(RECOVERIES)), st.text("abcdefghij _", min_size=1, max_size=20).map(str.strip)
       .filter(bool), st.integers(1, 20), st.sampled_from(OUTCOMES), MS, st.booleans(), MS | st.none(), MS)
def test_an_attempt_reads_back_from_its_log_entry_and_its_events_fields(behaviour, trigger, attempt, outcome,
                                                                        duration, contact, arrival, close):
    done = RecoveryOutcome(behaviour, trigger, attempt, outcome, duration,
                           arrival if contact and arrival is not None else None, close if contact else None)
    assert RecoveryOutcome.from_dict(json.loads(json.dumps(done.to_dict()))) == done  # as the record keeps it
    fields = {k: v for k, v in done.to_dict().items() if v is not None}  # as the event carries it
    assert RecoveryOutcome.from_dict(json.loads(json.dumps(fields))) == done


def test_an_arm_override_slows_the_arm_and_not_the_gripper():
    plan = Plan(np.array([0.0, 1.0]), np.array([[0.0, 0.0], [1.0, 2.0]]), np.array([0.0, 0.5]), np.array([0.02, 0.01]))
    t = np.array([0.0, 0.5, 1.0, 2.0])
    full, slow = plan.sample(t), plan.sample(t, arm_speed=0.5)
    assert full.shape == (4, 3)
    np.testing.assert_allclose(full[-1], [1.0, 2.0, 0.01])
    np.testing.assert_allclose(slow[:, 2], full[:, 2])  # the gripper keeps its timing
    assert slow[2, 0] < full[2, 0] and slow[3, 0] == pytest.approx(1.0)
    assert plan.duration(0.5) == pytest.approx(2.0) and plan.duration() == pytest.approx(1.0)


def _events(run, kind):
    return [e for e in run.events if e.kind == kind]


def test_without_a_recovery_a_slipped_grasp_fails_the_cycle():
    run = Run(_scenario(faults=[SLIP]))
    outcome = run.cycle()
    assert not outcome["success"] and not outcome["grasped"]
    assert "recoveries" not in outcome


def test_a_search_offset_recovers_a_slipped_grasp_and_the_record_says_so():
    run = Run(_scenario(faults=[SLIP], recovery=RETRY))
    sent, original = [], run.guard.envelope.apply

    def apply(*args, **kwargs):
        setpoint, events = original(*args, **kwargs)
        sent.append(setpoint.copy())
        return setpoint, events

    run.guard.envelope.apply = apply
    outcome = run.cycle()
    profile, q = run.cell.profile, np.array(sent)
    v = np.diff(q, axis=0) / 1e-3  # the recovery's chunks went through the envelope like the policy's
    assert (q >= profile.q_min).all() and (q <= profile.q_max).all()
    assert (np.abs(v) <= profile.array("velocity") * 1.002).all()
    assert (np.abs(np.diff(v, axis=0) / 1e-3) <= profile.array("acceleration") * 1.02).all()
    assert outcome["success"] and outcome["grasped"]
    log = outcome["recovery_log"]
    assert [r["behaviour"] for r in log] == ["retry_grasp"] * len(log) and log[-1]["outcome"] == "resumed"
    starts, ends = _events(run, "recovery_start"), _events(run, "recovery_end")
    assert len(starts) == len(ends) == len(log) == outcome["recoveries"]
    assert "after grasp_missed" in starts[0].reason
    assert ends[-1].reason == RecoveryOutcome.from_dict(log[-1]).reason()  # the words of the logged attempt
    assert outcome["features"]["recovery_resumed"] == 1.0 and "recovery_log" not in outcome["features"]
    # the cycle's geometry is the policy's own grasp, not the recovery's
    assert abs(outcome["grasp_offset_mm"][0]) > 3.0


def test_a_late_recovery_closes_before_it_arrives_and_escalates():
    run = Run(_scenario(faults=[SLIP, {"kind": "late_recovery", "speed_scale": 0.5}], recovery=RETRY))
    outcome = run.cycle()
    assert not outcome["success"]
    first = RecoveryOutcome.from_dict(outcome["recovery_log"][0])
    assert first.outcome == "failed" and first.arrival_s > first.close_s
    assert [r["outcome"] for r in outcome["recovery_log"]][:2] == ["failed", "escalated"]
    assert outcome["recovery_log"][2]["behaviour"] == "operator"
    assert any(e.kind == "protective_stop" and e.category == 2 for e in run.events)  # power kept
    assert _events(run, "reset")


def test_an_operator_hold_longer_than_the_cycle_time_out_is_held_whole_and_ends_in_its_reset():
    """A 30 s hold was cut off by the 12 s time-out after 6 s: the hold was released without a reset and
    the next cycle's policy started from mid-cell."""
    hold_s = 14.0
    recovery = {"behaviours": [RETRY["behaviours"][0], {"do": "operator", "hold_s": hold_s}]}
    shift = {"kind": "fixture_shift", "at_cycle": 0, "dx_mm": 15.0}  # beyond the retry's search: it escalates to the operator
    run = Run(_scenario(faults=[shift], recovery=recovery, production_cycles=2))
    first = run.cycle()
    hold = next(e for e in _events(run, "protective_stop") if "hand-over" in e.reason)
    reset, resume = _events(run, "reset")[0], next(e for e in _events(run, "resume") if "hand-over" in e.reason)
    assert (reset.t_ns - hold.t_ns) * 1e-9 == pytest.approx(hold_s, abs=0.01)
    assert resume.t_ns >= reset.t_ns  # released only by the operator's reset
    assert first["recovery_log"][-1]["behaviour"] == "operator" and first["recovery_log"][-1]["duration_s"] > hold_s
    home = np.asarray(run.cell.q_home)
    assert np.abs(run.guard.reference[:-1] - home[:-1]).max() < 1e-3  # the next cycle starts at home
    ticks = run.ticks  # the cycle's features cover all of it, not its first 12 s
    assert (ticks.stamp(ticks.n - 1) - ticks.stamp(0)) * 1e-9 > hold_s + 2.0 and not first["timed_out"]
    second = run.cycle()
    assert not any(e.kind == "tracker_failed" for e in run.events), "the next cycle started off its pose"
    assert second["recovery_log"][0]["behaviour"] == "retry_grasp"


def test_the_late_recovery_fault_slows_recoveries_from_its_cycle_only():
    fault = _scenario(production_cycles=10, faults=[{"kind": "late_recovery", "at_cycle": 3, "speed_scale": 0.4}]).faults[0]
    assert [fault.recovery_speed(c) for c in (2, 3, 9)] == [1.0, 0.4, 0.4]
    with pytest.raises(ScenarioError, match="speed_scale"):
        _scenario(faults=[{"kind": "late_recovery", "speed_scale": 1.5}])


def test_a_part_presented_out_of_place_is_picked_where_the_camera_sees_it():
    misplaced = {"kind": "part_misplaced", "rate": 1.0, "dx_mm": 8.0}  # beyond what the program corrects
    assert not Run(_scenario(faults=[misplaced])).cycle()["success"]
    run = Run(_scenario(faults=[misplaced], recovery={"behaviours": [
        {"do": "reregister_datum", "trigger": "grasp_missed"}]}))
    outcome = run.cycle()
    assert outcome["success"] and [r["outcome"] for r in outcome["recovery_log"]] == ["resumed"]


def test_every_behaviour_plans_from_where_the_cell_is_and_ends_at_home():
    from cellguard.robot.arm_cell import ArmPickPlace

    cell = ArmPickPlace()
    cell.begin_cycle(0)
    q = np.array(cell.q_home)
    for name, cls in RECOVERIES.items():
        plan = cls(do=name).plan(cell, q, 1, q)
        start, end = plan.sample(np.array([0.0, plan.duration() + 1.0]))
        np.testing.assert_allclose(start, q, atol=1e-9, err_msg=name)
        np.testing.assert_allclose(end[:-1], cell.q_home[:-1], atol=1e-9, err_msg=name)
        assert end[-1] == pytest.approx(cell.gripper_open), name
        assert (plan.contact_q is None) == (plan.close_t is None), name
    held = RECOVERIES["operator"](do="operator", hold_s=2.0).plan(cell, q, 1, q)
    np.testing.assert_allclose(held.sample(np.array([1.9])), [q])  # still during the hand-over


def test_the_move_home_after_the_last_attempt_is_not_cut_off_by_the_cycle_time_out():
    """Attempt 5 ended 0.5 s before the 12 s time-out: the move home was cut off 1.06 rad from home, still
    moving, and the next cycle started there (limit interventions, then a workspace stop)."""
    slip = {"kind": "intermittent_slip", "rate": 1.0, "dx_mm": 25.0, "seed": 3}
    run = Run(_scenario(seed=7, production_cycles=2, faults=[slip], recovery={"behaviours": [
        {"do": "retry_grasp", "trigger": "grasp_missed", "attempts": 5, "search_mm": 1.0}]}))
    first = run.cycle()
    assert [r["outcome"] for r in first["recovery_log"]][-1] == "gave_up" and not first["timed_out"]
    home = np.asarray(run.cell.q_home)
    assert np.abs(run.guard.reference[:-1] - home[:-1]).max() < 1e-3  # the next cycle starts at home
    start = len(run.events)
    run.cycle()
    assert not [e.kind for e in run.events[start:] if e.kind in ("limit_intervention", "workspace_stop")]


def test_the_attempt_the_per_cycle_limit_ends_is_the_one_that_gave_up():
    slip = {"kind": "intermittent_slip", "rate": 1.0, "dx_mm": 25.0, "seed": 3}
    run = Run(_scenario(seed=7, faults=[slip], recovery={"max_per_cycle": 2, "behaviours": [
        {"do": "retry_grasp", "trigger": "grasp_missed", "attempts": 3, "search_mm": 1.0, "then": "back_off"},
        {"do": "back_off", "attempts": 3}]}))
    outcome = run.cycle()
    assert [r["outcome"] for r in outcome["recovery_log"]] == ["failed", "gave_up"]
    assert _events(run, "recovery_end")[-1].reason.startswith("no recovery left (the limit of 2 recoveries")
