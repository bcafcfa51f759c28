"""An operator hand-over or a rehome ends its attempt ``resumed`` (its plan ran out) but its cycle failed: neither the
cycle's ``recovery_resumed`` nor the diagnosis counts it as a recovery that got the cell running again."""

from __future__ import annotations

import pytest

from cellguard.diagnose.cycles import Cycle
from cellguard.diagnose.recovery import attempts_of, recovery_finding
from cellguard.robot.recovery.outcome import RecoveryOutcome
from cellguard.runtime import Run
from cellguard.scenario import parse_scenario


def _cycle(i, phase="production", success=True, recoveries=0):
    return Cycle(i, phase, success, {"success": float(success), "recoveries": float(recoveries),
                                     "after_recovery": 0.0, "current_rms.elbow": 1.0, "grasp_offset_x_mm": 0.0})


def _retry(outcome, attempt, arrival=1.6):
    return RecoveryOutcome("retry_grasp", "grasp_missed", attempt, outcome, 2.0, arrival, 1.8)


def _last_resort(behaviour):
    """The attempt a hand-over or a rehome logs: no contact, its plan ran out."""
    return RecoveryOutcome(behaviour, "escalation from retry_grasp", 1, "resumed", 1.6)


def _rows(logs):
    return attempts_of([{"cycle": c, "features": {}, "recovery_log": [o.to_dict() for o in log]}
                        for c, log in logs.items()])


@pytest.mark.parametrize("behaviour", ["operator", "rehome"])
def test_retries_that_end_in_a_last_resort_every_cycle_are_recoveries_without_effect(behaviour):
    cycles = [_cycle(i, "acceptance", recoveries=i in (1, 3)) for i in range(6)]
    cycles += [_cycle(i, success=False, recoveries=3) for i in range(6, 10)]
    logs = {1: [_retry("resumed", 1)], 3: [_retry("resumed", 1)]}
    logs |= {i: [_retry("failed", 1), _retry("escalated", 2), _last_resort(behaviour)]  # on time, on no part
             for i in range(6, 10)}
    f = recovery_finding(cycles, _rows(logs))
    assert f is not None and f.cause == "recovery" and f.cycle == 6
    assert ("recoveries repeated without effect in 4 of 4 production cycles with a recovery (12 attempts, none "
            "resumed the cell)") in f.evidence


def test_a_hand_over_at_acceptance_is_no_part_picked_again():
    cycles = [_cycle(i, "acceptance", recoveries=i in (1, 3, 4)) for i in range(6)]
    cycles += [_cycle(i, success=i not in (8, 10), recoveries=i in (8, 10)) for i in range(6, 12)]
    logs = {1: [_retry("resumed", 1)], 3: [_retry("resumed", 1)],
            4: [_retry("failed", 1), _retry("escalated", 2), _last_resort("operator")]}
    logs |= {c: [_retry("failed", 1, 3.2), _retry("gave_up", 2, 3.2)] for c in (8, 10)}
    f = recovery_finding(cycles, _rows(logs))
    assert "they picked the part again in 0 of 2 cycles vs 2 of 3 at acceptance" in f.evidence


def test_a_cycle_a_hand_over_ended_is_not_recovery_resumed():
    slip = {"kind": "intermittent_slip", "rate": 1.0, "dx_mm": -17.0}  # beyond the search: every retry misses
    recovery = {"behaviours": [{"do": "retry_grasp", "trigger": "grasp_missed", "attempts": 2, "search_mm": 4.0,
                                "then": "operator"}, {"do": "operator", "hold_s": 0.3}]}
    run = Run(parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 0, "production_cycles": 1,
                              "faults": [slip], "recovery": recovery}))
    outcome = run.cycle()
    log = outcome["recovery_log"]
    assert [(r["behaviour"], r["outcome"]) for r in log][-1] == ("operator", "resumed") and not outcome["success"]
    assert outcome["features"]["recovery_resumed"] == 0.0
