"""The attempts of the cycle a killed run ended in (no row: its outcome unknown) are not judged late, as they count in
no late cycle. Counted among the late attempts all the same ("3 recovery attempts from cycle 3 on" over 2 late cycles),
they were enough on their own to name a ``recovery`` in a run whose cycles that ended had one late attempt."""

from __future__ import annotations

from cellguard.diagnose.cycles import Cycle
from cellguard.diagnose.recovery import recovery_finding
from cellguard.robot.recovery.outcome import RecoveryOutcome


def _attempt(outcome: str, arrival_s: float | None) -> RecoveryOutcome:
    return RecoveryOutcome("retry_grasp", "grasp_missed", 1, outcome, 2.0, arrival_s, 1.0)


def test_the_attempts_of_the_cycle_a_run_was_killed_in_name_no_late_recovery():
    cycles = [Cycle(i, "acceptance", True, {}) for i in range(3)] + [Cycle(3, "production", True, {})]
    attempts = ([(i, _attempt("resumed", 0.5)) for i in range(3)] + [(3, _attempt("resumed", 2.0))]
                + [(4, _attempt("failed", None)), (4, _attempt("failed", 2.0))])  # cycle 4: killed in it, no row
    assert recovery_finding(cycles, attempts) is None
    ended = recovery_finding([*cycles, Cycle(4, "production", False, {})], attempts)  # the same cycle with its row
    assert ended is not None and ended.evidence[0].startswith("3 recovery attempts from cycle 3 on"), ended
    assert "they picked the part again in 1 of 2 cycles vs 3 of 3 at acceptance" in ended.evidence
