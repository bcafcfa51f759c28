"""A safety stop while a recovery drives the cell.

A category 1 stop (power removed) mid-attempt was logged ``resumed`` (its plan ran out on a robot without
power). A category 2 stop held the arm while the attempt's plan clock ran on: the gripper shut before the
held arm arrived, the signature the diagnosis reads as a late recovery.
"""

from __future__ import annotations

from cellguard.robot.protocol import SafetyInputs
from cellguard.runtime import Run
from cellguard.scenario import parse_scenario

RECOVERY = {"max_per_cycle": 4, "behaviours": [
    {"do": "retry_grasp", "trigger": "grasp_missed", "attempts": 2, "search_mm": 5.0, "then": "operator"},
    {"do": "operator", "hold_s": 0.5}]}


def _stopped_during_the_first_attempt(monkeypatch, category: int, after_s: float, for_s: float, dx_mm: float):
    """A run whose safety input asks for a ``category`` stop ``after_s`` into its first recovery, for ``for_s``."""
    run = Run(parse_scenario({"cell": "arm-pick-place", "seed": 7, "acceptance_cycles": 0, "production_cycles": 1,
                              "faults": [{"kind": "intermittent_slip", "rate": 1.0, "dx_mm": dx_mm, "seed": 3}],
                              "recovery": RECOVERY}))
    safety = run.cell.safety

    def pressed():
        start = next((e.t_ns for e in run.events if e.kind == "recovery_start"), None)
        t = run.clock.now()
        if start is not None and start + after_s * 1e9 <= t < start + (after_s + for_s) * 1e9:
            return SafetyInputs(category)
        return safety()

    monkeypatch.setattr(run.cell, "safety", pressed)
    return run, run.cycle()


def test_power_removed_mid_attempt_cuts_it_off_and_starts_nothing_after_it(monkeypatch):
    run, outcome = _stopped_during_the_first_attempt(monkeypatch, 1, 0.5, 0.3, -5.0)
    assert any(e.kind == "power_removed" for e in run.events)
    log = outcome["recovery_log"]
    assert [r["outcome"] for r in log] == ["cut_off"]  # one attempt, and not 'resumed'
    assert log[0]["duration_s"] < 1.0  # it ended at the stop, not when its plan would have run out
    assert outcome["recovery_resumed"] == 0.0 and not outcome["success"]


def test_a_held_arm_pauses_the_attempt_so_the_gripper_waits_for_it(monkeypatch):
    run, outcome = _stopped_during_the_first_attempt(monkeypatch, 2, 0.5, 1.2, 5.0)
    assert any(e.kind == "protective_stop" and e.category == 2 for e in run.events)
    first = outcome["recovery_log"][0]
    assert first["arrival_s"] is not None and first["arrival_s"] < first["close_s"]  # arrived, then the gripper shut
    _, unstopped = _stopped_during_the_first_attempt(monkeypatch, 2, 0.5, 0.0, 5.0)
    assert first["duration_s"] >= unstopped["recovery_log"][0]["duration_s"] + 1.2  # it waited out the hold


def test_a_stop_that_outlasts_the_cycle_time_out_ends_the_cycle_and_cuts_the_attempt_off(monkeypatch):
    """The time-out waits for an attempt that moves, not for one a stop holds (it may never clear)."""
    _, outcome = _stopped_during_the_first_attempt(monkeypatch, 2, 0.5, 60.0, 5.0)
    assert outcome["timed_out"] and outcome["cycle_time_s"] < 13.0
    assert [r["outcome"] for r in outcome["recovery_log"]] == ["cut_off"]
