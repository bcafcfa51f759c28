"""The recovery cause from recorded attempts, what fixed each finding, and advice, on cycles built by hand (each
cycle's attempts in its ``recovery_log``, as the runner writes it)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np

from cellguard.diagnose.cause import CAUSES, Finding
from cellguard.diagnose.cycles import Cycle
from cellguard.diagnose.recovery import (advice, advice_lines, attempts_of, fixes, policy_cycles, recovery_finding,
                                         with_running_again, without_recovery_motion)
from cellguard.diagnose.site_history import save_fixes, site_history
from cellguard.robot.recovery.outcome import RecoveryOutcome


def _cycle(i, phase="production", success=True, recoveries=0, after=0):
    return Cycle(i, phase, success, {"success": float(success), "recoveries": float(recoveries),
                                     "after_recovery": float(after), "current_rms.elbow": 1.0,
                                     "grasp_offset_x_mm": 0.0})


def _end(cycle, outcome, arrival, close=1.8, attempt=1, behaviour="retry_grasp"):
    return cycle, RecoveryOutcome(behaviour, "grasp_missed", attempt, outcome, 2.0, arrival, close)


def _attempts(ends):
    """The attempts as the diagnosis reads them: from cycle rows whose recovery_log holds them."""
    logs = {}
    for cycle, done in ends:
        logs.setdefault(cycle, []).append(done.to_dict())
    return attempts_of([{"cycle": c, "features": {}, "recovery_log": log} for c, log in logs.items()])


def _run(late_arrival):
    cycles = [_cycle(i, "acceptance", recoveries=i in (1, 3)) for i in range(6)]
    cycles += [_cycle(i, success=i not in (8, 10), recoveries=i in (8, 10)) for i in range(6, 12)]
    events = [_end(1, "resumed", 1.6), _end(3, "resumed", 1.6)]
    events += [_end(c, o, late_arrival, attempt=a) for c in (8, 10) for a, o in ((1, "failed"), (2, "gave_up"))]
    return cycles, events


def test_recoveries_late_at_contact_are_named_recovery_with_the_arrival_as_evidence():
    cycles, events = _run(late_arrival=3.2)
    f = recovery_finding(cycles, _attempts(events))
    assert "recovery" in CAUSES and f.cause == "recovery" and f.cycle == 8 and f.confidence >= 0.9
    assert "arrived at contact 3.20 s after they started (median) vs 1.60 s for the 2 acceptance recoveries" in f.evidence[0]
    assert "1.40 s before the arm arrived" in f.evidence[1]
    assert "picked the part again in 0 of 2 cycles vs 2 of 2 at acceptance" in f.evidence[2]


def test_recoveries_on_time_are_not_a_cause():
    cycles, events = _run(late_arrival=1.62)
    events = [(c, dataclasses.replace(d, outcome="resumed") if d.attempt == 2 else d) for c, d in events]
    assert recovery_finding(cycles, _attempts(events)) is None


def test_a_next_cycle_that_fails_after_each_recovery_is_a_recovery_cause():
    cycles = [_cycle(i, "acceptance") for i in range(5)]
    cycles += [_cycle(5, recoveries=1), _cycle(6, success=False, after=1), _cycle(7),
               _cycle(8, recoveries=1), _cycle(9, success=False, after=1), _cycle(10)]
    events = [_end(5, "resumed", 1.6), _end(8, "resumed", 1.6)]
    f = recovery_finding(cycles, _attempts(events))
    assert f.cycle == 6 and "the cycle after a recovery failed in 2 of 2" in f.evidence[0]


def test_recovery_cycles_leave_the_baseline_and_their_motion_out_of_drift():
    acceptance = [_cycle(i, "acceptance", recoveries=i == 2) for i in range(6)]
    seen = policy_cycles(acceptance)
    assert set(seen[2].features) == {"success", "grasp_offset_x_mm"} and seen[3] is acceptance[3]
    few = [_cycle(i, "acceptance", recoveries=i > 1) for i in range(6)]
    assert policy_cycles(few) == few  # too few cycles without a recovery: all stay as they are
    names = ("current_rms.elbow", "grasp_offset_x_mm", "success")
    z = without_recovery_motion(names, acceptance[1:3], np.ones((2, 3)))
    assert np.isnan(z[1, 0]) and z[1, 1] == 1.0 and z[1, 2] == 1.0 and not np.isnan(z[0]).any()


def test_fixes_belong_to_the_latest_finding_and_advice_ranks_by_success_rate(tmp_path):
    cycles = [_cycle(i, success=i != 9) for i in range(4, 12)]
    events = [_end(5, "resumed", 1.6), _end(6, "resumed", 1.6), _end(9, "failed", 1.6),
              _end(9, "resumed", 1.6, attempt=2, behaviour="back_off"), _end(10, "resumed", 1.6)]
    findings = [Finding("tool_slip", 4, 0.9, ("slip",)), Finding("fixture_shift", 9, 0.8, ("moved",))]
    own = fixes(findings, cycles, _attempts(events))
    assert [(r["cause"], r["recovery"], r["tried"], r["fixed"]) for r in own] == [
        ("tool_slip", "retry_grasp", 2, 2), ("fixture_shift", "back_off", 1, 0), ("fixture_shift", "retry_grasp", 2, 1)]
    lines = [f.evidence[-1] for f in with_running_again(findings, own)]
    assert lines == ["what got the cell running again: retry_grasp (2 of 2 cycles)",
                     "what got the cell running again: retry_grasp (1 of 2 cycles)"]
    for name, site in (("a", "plant-1"), ("b", "plant-1"), ("c", "plant-2")):
        (tmp_path / name).mkdir()
        save_fixes(tmp_path / name, {"record_id": name, "site": site}, own)
    history = site_history(tmp_path / "a", "plant-1")
    assert {r["record"] for r in history} == {"b"}
    advised = advice(findings, history + [{"cause": "fixture_shift", "recovery": "reregister_datum", "tried": 4,
                                           "fixed": 4, "record": "d"}])
    shift = next(a for a in advised if a["cause"] == "fixture_shift")
    assert [(r["recovery"], r["fixed"], r["tried"]) for r in shift["recoveries"]] == [
        ("reregister_datum", 4, 4), ("retry_grasp", 1, 2), ("back_off", 0, 1)]
    json.dumps(advised)  # the advice is JSON as it stands


def test_advice_puts_this_site_first_then_the_fleet_with_its_customer_count():
    findings = [Finding("tool_slip", 4, 0.9, ("slip",))]
    history = [{"cause": "tool_slip", "recovery": "back_off", "tried": 3, "fixed": 1, "record": "a"},
               {"cause": "tool_slip", "recovery": "retry_grasp", "tried": 40, "fixed": 38, "customers": 6,
                "scope": "fleet"},
               {"cause": "friction", "recovery": "rehome", "tried": 9, "fixed": 9, "customers": 5, "scope": "fleet"}]
    advised = advice(findings, history)
    assert [(r["scope"], r["recovery"], r["fixed"], r["tried"]) for r in advised[0]["recoveries"]] == [
        ("site", "back_off", 1, 3), ("fleet", "retry_grasp", 38, 40)]
    line = advice_lines(advised)["tool_slip", 4]
    assert line == ("seen before at this site: back_off fixed it in 1 of 3 cycles (1 record(s)); "
                    "at other sites in the fleet: retry_grasp fixed it in 38 of 40 signatures (6 customers)")


def test_a_fleet_signature_carries_the_recovery_that_fixed_its_finding():
    import datetime as dt

    from cellguard.fleet.signature import signatures_of

    diagnosis = {"findings": [{"cause": "tool_slip", "cycle": 4, "confidence": 0.9, "signals": []},
                              {"cause": "recovery", "cycle": 9, "confidence": 0.9, "signals": []},
                              {"cause": "friction", "cycle": 2, "confidence": 0.9, "signals": []}],
                 "fixes": [{"cause": "tool_slip", "cycle": 4, "recovery": "back_off", "tried": 3, "fixed": 1},
                           {"cause": "tool_slip", "cycle": 4, "recovery": "retry_grasp", "tried": 2, "fixed": 2},
                           {"cause": "recovery", "cycle": 9, "recovery": "operator", "tried": 2, "fixed": 0}]}
    sigs = signatures_of(diagnosis, {}, "t1", "s1", dt.date(2026, 11, 23))
    assert [(s.cause, s.recovery, s.recovery_outcome) for s in sigs] == [
        ("tool_slip", "retry_grasp", "success"), ("recovery", "operator", "failed"), ("friction", None, None)]
