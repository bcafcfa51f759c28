"""A run killed mid-cycle (SIGKILL to its process group) keeps the recovery attempts of that cycle in its diagnosis.

A cycle's ``recovery_log`` is written with its row at the cycle's end, each ``recovery_end`` event when its attempt
ends: the cycle the run was killed in has events and no row. Read from the log alone, its attempts were lost (a
record of scenarios/recovery.yaml killed in cycle 25 lost its ``recovery`` finding). Each event carries its attempt
as fields, read for a cycle with no row; the words of a record written before events carried them are parsed.
"""

from __future__ import annotations

import dataclasses
import os
import signal
import subprocess
import sys
import time

import pytest
import yaml

from cellguard.diagnose.cycles import Cycle
from cellguard.diagnose.diagnosis import diagnose
from cellguard.diagnose.from_record import diagnose_record
from cellguard.diagnose.recovery import recovery_finding
from cellguard.errors import CellguardError
from cellguard.record.reader import open_record
from cellguard.robot.recovery.outcome import RecoveryOutcome

# as test_recovery_log_read, 4 cycles longer: slips, each recovered by a second grasp, in production cycles 5, 8, 9,
# 12 and 14 (a tool_slip finding from cycle 5 on)
SCENARIO = {"cell": "arm-pick-place", "seed": 4, "acceptance_cycles": 5, "production_cycles": 10,
            "faults": [{"kind": "intermittent_slip", "rate": 0.4, "dx_mm": -5.0, "seed": 27}],
            "recovery": {"behaviours": [{"do": "retry_grasp", "trigger": "grasp_missed", "attempts": 2}]}}


def _unlogged(out) -> list[int]:
    """Cycles whose ``recovery_end`` events the record holds and whose row it does not (none while unreadable)."""
    try:
        with open_record(out) as record:
            rows = {c.cycle for c in record.cycles()}
            return sorted({e.cycle for e in record.events() if e.kind == "recovery_end" and e.cycle not in rows})
    except CellguardError:
        return []


@pytest.fixture(scope="module")
def killed(tmp_path_factory):
    """The record of a run killed (the loop and its recorder, SIGKILL) once a cycle from 12 on has ended an attempt
    and not yet its row: the group is stopped, the record read again, and killed while so."""
    folder = tmp_path_factory.mktemp("killed")
    scenario, out = folder / "scenario.yaml", folder / "run"
    scenario.write_text(yaml.safe_dump(SCENARIO))
    proc = subprocess.Popen([sys.executable, "-c", "from cellguard.cli import app; app()", "run", str(scenario),
                             "--out", str(out)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while proc.poll() is None and time.monotonic() < deadline:
            if [c for c in _unlogged(out) if c >= 12]:
                os.killpg(proc.pid, signal.SIGSTOP)
                if [c for c in _unlogged(out) if c >= 12]:  # still: nothing more is written
                    break
                os.killpg(proc.pid, signal.SIGCONT)  # its row came meanwhile: the next recovery
            time.sleep(0.02)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL, proc.stderr.read()
    unlogged = _unlogged(out)
    assert len(unlogged) == 1, unlogged
    with open_record(out) as record:
        cycles, events, context = list(record.cycles()), list(record.events()), dict(record.context)
    return out, unlogged[0], cycles, events, context


def test_the_attempts_of_the_cycle_a_run_was_killed_in_are_in_its_diagnosis(killed):
    out, cycle, cycles, events, _ = killed
    assert cycle not in {c.cycle for c in cycles} and max(c.cycle for c in cycles) == cycle - 1
    ended = [e for e in events if e.kind == "recovery_end" and e.cycle == cycle]
    assert ended and all(e.recovery is not None for e in ended)  # the attempt's fields, with its event
    attempts = [RecoveryOutcome.from_dict(e.recovery) for e in ended]
    assert [a.reason() for a in attempts] == [e.reason for e in ended]  # the same attempt as its words
    diagnosis = diagnose_record(out)
    assert [r for r in diagnosis.recoveries if r["cycle"] == cycle] == [{"cycle": cycle, **a.to_dict()}
                                                                        for a in attempts]
    logged = [{"cycle": c.cycle, **r} for c in cycles for r in c.outcome.get("recovery_log", [])]
    assert [r for r in diagnosis.recoveries if r["cycle"] != cycle] == logged  # the other cycles: from their rows


def test_the_killed_cycle_is_read_from_its_events_fields_not_their_words(killed):
    _, cycle, cycles, events, context = killed
    reworded = [dataclasses.replace(e, reason=f"Recovery step finished ({i})") if e.kind == "recovery_end" else e
                for i, e in enumerate(events)]
    as_recorded, as_reworded = diagnose(cycles, events, context), diagnose(cycles, reworded, context)
    assert any(r["cycle"] == cycle for r in as_reworded.recoveries)
    assert as_reworded.recoveries == as_recorded.recoveries and as_reworded.findings == as_recorded.findings


def test_a_record_from_before_events_carried_the_fields_has_the_killed_cycles_words_read(killed):
    """Its events have words alone: they are parsed for the cycle with no row, and give the same attempts."""
    _, cycle, cycles, events, context = killed
    older = [dataclasses.replace(e, recovery=None) for e in events]
    read = diagnose(cycles, older, context).recoveries
    assert any(r["cycle"] == cycle for r in read) and read == diagnose(cycles, events, context).recoveries
    # words are read for no cycle that has its row: reworded there, nothing changes
    reworded = [dataclasses.replace(e, reason="done") if e.cycle != cycle else e for e in older]
    assert diagnose(cycles, reworded, context).recoveries == diagnose(cycles, events, context).recoveries


def test_the_cycle_a_run_was_killed_in_counts_in_no_fix(killed):
    """Its outcome is unknown: counted as tried and not fixed, a killed record said retry_grasp fixed 3 of 4 cycles
    where the whole run fixed all of them, and ``fixes`` reaches later records' advice and the fleet."""
    out, cycle, cycles, events, context = killed
    diagnosis = diagnose_record(out)
    assert any(r["cycle"] == cycle for r in diagnosis.recoveries)  # its attempts are still read
    without = diagnose(cycles, [e for e in events if e.cycle != cycle], context)
    assert diagnosis.fixes and diagnosis.fixes == without.fixes
    assert all(f["fixed"] == f["tried"] for f in diagnosis.fixes), diagnosis.fixes  # each slip: a second grasp


def _attempt(outcome, arrival_s=0.5):
    return RecoveryOutcome("retry_grasp", "grasp_missed", 1, outcome, 2.0, arrival_s, 1.0)


def _cycles(production):
    """Acceptance cycles 0-2, then the production cycles ``production`` (index: success)."""
    return ([Cycle(i, "acceptance", True, {}) for i in range(3)]
            + [Cycle(i, "production", ok, {}) for i, ok in production.items()])


def test_the_cycle_a_run_was_killed_in_is_not_a_recovery_repeated_without_effect():
    """Two failed attempts in it and no row: its next attempt might have resumed the cell."""
    attempts = ([(i, _attempt("resumed")) for i in range(3)] + [(3, _attempt("failed")), (3, _attempt("failed")),
                                                                (4, _attempt("resumed"))]
                + [(5, _attempt("failed")), (5, _attempt("failed"))])
    assert recovery_finding(_cycles({3: False, 4: True}), attempts) is None
    ended = recovery_finding(_cycles({3: False, 4: True, 5: False}), attempts)  # the same cycle with its row
    assert ended is not None and "repeated without effect in 2 of 3 production cycles" in ended.evidence[0]


def test_the_cycle_a_run_was_killed_in_is_no_late_cycle_that_failed_to_pick():
    """Whether the part was picked again in it is unknown, and its attempts are not judged: none counts as late."""
    attempts = ([(i, _attempt("resumed")) for i in range(3)]
                + [(3, _attempt("resumed", 2.0)), (4, _attempt("failed", 2.0)), (5, _attempt("failed", 2.0))])
    found = recovery_finding(_cycles({3: True, 4: False}), attempts)
    assert found is not None and found.evidence[0].startswith("2 recovery attempts from cycle 3 on")
    assert "they picked the part again in 1 of 2 cycles vs 3 of 3 at acceptance" in found.evidence


@pytest.mark.parametrize("attempt, duration", [("9" * 5000, "1.000"), ("1", "1.2.3"), ("1", "9" * 400 + ".000")],
                         ids=["an attempt of 5000 digits", "1.2.3 s", "a duration of 400 digits"])
def test_crafted_words_that_hold_no_number_are_no_attempt(attempt, duration):
    """Parsed as the words of an older record, they ended the diagnosis in a ValueError (an int of over 4,300 digits,
    '1.2.3') or read as an attempt of infinite duration."""
    words = f"retry_grasp: attempt {attempt} after grasp_missed, {duration} s; outcome failed"
    assert RecoveryOutcome.parse(words) is None
    assert RecoveryOutcome.parse(words.replace(attempt, "1").replace(duration, "1.000")) is not None
