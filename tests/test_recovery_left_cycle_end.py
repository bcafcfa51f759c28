"""What a cycle's end says of its recoveries: the flat arrival and close of one attempt, the end of an attempt the
cycle's end cut off stamped at that end, and ``resumed`` for an attempt the cell's task ended with no failed check.

The cycle's ``recovery_arrival_s`` was the latest attempt's arrival and its ``recovery_close_s`` the earliest
attempt's close: a retry_grasp (arrived 1.595 s, shut 1.800 s) escalated to a back_off (3.161 s, 3.600 s) read
3.161 against 1.800 in every cycle, a gripper shut before an arrival that no attempt had. An attempt a stop of the run
cut off was stamped at the tick before the cycle's end: its ``recovery_end`` (5.245 s) came before the
``operator_stop`` (5.246 s) that caused it.
"""

from __future__ import annotations

import pytest
from test_runtime_operator_stop import _run_pressing

from cellguard.control.events import EventKind
from cellguard.robot.recovery.outcome import RecoveryOutcome
from cellguard.runtime import Run
from cellguard.scenario import parse_scenario

SLIP = {"kind": "intermittent_slip", "rate": 1.0, "dx_mm": -5.0}  # every cycle: the grasp misses, the +x retry too


def _run(recovery: dict, faults: list, cycles: int = 1, seed: int = 0) -> Run:
    return Run(parse_scenario({"cell": "arm-pick-place", "seed": seed, "acceptance_cycles": 0,
                               "production_cycles": cycles, "faults": faults, "recovery": recovery}))


def _pair(outcome: dict) -> tuple[float | None, float | None]:
    features = outcome["features"]
    return features.get("recovery_arrival_s"), features.get("recovery_close_s")


def test_a_cycles_arrival_and_close_are_one_attempts():
    run = _run({"behaviours": [{"do": "retry_grasp", "trigger": "grasp_missed", "attempts": 1, "then": "back_off"},
                               {"do": "back_off"}]}, [SLIP])
    outcome = run.cycle()
    log = [RecoveryOutcome.from_dict(r) for r in outcome["recovery_log"]]
    assert [o.behaviour for o in log] == ["retry_grasp", "back_off"]
    assert all(o.arrival_s < o.close_s for o in log)  # every attempt arrived before its gripper shut
    retry = log[0]
    assert _pair(outcome) == (retry.arrival_s, retry.close_s)  # the one that arrived latest against its close
    assert outcome["features"]["recovery_arrival_s"] < outcome["features"]["recovery_close_s"]
    # what recoveries do is no intervention of the guard's: their events stay routine (see the report)
    assert outcome["features"]["interventions"] == 0.0
    assert EventKind.RECOVERY_START.routine and EventKind.RECOVERY_END.routine


def test_an_attempt_that_shut_before_it_arrived_is_the_one_the_cycle_shows():
    late = {"kind": "late_recovery", "speed_scale": 0.5}  # the arm at half speed, the gripper on the plan's time
    run = _run({"behaviours": [{"do": "retry_grasp", "trigger": "grasp_missed", "attempts": 2, "then": "operator"},
                               {"do": "operator", "hold_s": 0.3}]}, [SLIP, late])
    outcome = run.cycle()
    contact = [o for o in map(RecoveryOutcome.from_dict, outcome["recovery_log"]) if o.close_s is not None]
    worst = max(contact, key=lambda o: o.arrival_s - o.close_s)
    assert worst.arrival_s > worst.close_s
    assert _pair(outcome) == (worst.arrival_s, worst.close_s)


@pytest.mark.parametrize("held", [True, False], ids=["arm held still for an operator", "mid retry_grasp"])
def test_an_attempt_a_stop_of_the_run_cut_off_ends_when_the_stop_came(held):
    """Held still, the stop ends the cycle on the tick it comes (the cut-off attempt's end was stamped a tick before
    it); mid-move, the arm brakes first."""
    shift = {"kind": "fixture_shift", "at_cycle": 0, "dx_mm": 15.0}  # beyond the retry's search
    run = _run({"behaviours": [{"do": "retry_grasp", "trigger": "grasp_missed", "then": "operator"},
                               {"do": "operator", "hold_s": 20.0}]}, [shift], cycles=2, seed=7)

    def ready() -> bool:
        if not held:
            return run.recovery.attempting
        hold = next((e.t_ns for e in run.events if e.kind == "protective_stop"), None)
        return hold is not None and run.clock.now() - hold >= 1e9  # a second into the hold: the arm is still

    _run_pressing(run, lambda writes: ready() and not run.events.has("operator_stop"))
    assert run.stopped == "operator stop (SIGINT)"
    stop = next(e for e in run.events if e.kind == "operator_stop")
    end = [e for e in run.events if e.kind == "recovery_end"][-1]
    assert end.recovery["outcome"] == "cut_off"
    assert end.t_ns >= stop.t_ns, "the attempt's end read before the stop that ended it"
    start = [e for e in run.events if e.kind == "recovery_start"][-1]
    assert end.recovery["duration_s"] == pytest.approx((end.t_ns - start.t_ns) * 1e-9, abs=1e-3)


def test_an_attempt_the_cells_task_ended_with_no_failed_check_resumed_the_cell():
    """The task ends the cycle once the arm is home and still, 75 ms before an operator hand-over's plan ran out:
    nothing was cut off, the attempt is ``resumed`` (the README's ``cut_off`` list said otherwise)."""
    shift = {"kind": "fixture_shift", "at_cycle": 0, "dx_mm": 15.0}
    run = _run({"behaviours": [{"do": "retry_grasp", "trigger": "grasp_missed", "then": "operator"},
                               {"do": "operator", "hold_s": 0.5}]}, [shift], seed=7)
    outcome = run.cycle()
    operator = RecoveryOutcome.from_dict(outcome["recovery_log"][-1])
    assert operator.behaviour == "operator" and operator.outcome == "resumed"
    assert not outcome["timed_out"] and not any(e.category is not None and "hand-over" not in e.reason
                                                for e in run.events)  # no stop but the hold's own
    end, last_tick = [e for e in run.events if e.kind == "recovery_end"][-1], run.ticks.stamp(run.ticks.n - 1)
    assert last_tick - end.t_ns <= run.cell.dt_ns  # ended by the cycle's end, not by its plan running out
