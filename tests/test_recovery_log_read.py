"""The diagnosis reads each recovery attempt from the cycle's structured ``recovery_log``, not from the words of
its ``recovery_end`` event: the words are for a technician, and a reworded message changed what the diagnosis
read (an attempt whose words no longer matched the pattern vanished from it, its cycle's fixes with it).

One simulated run with slips and retry_grasp, read back from its record; the same record's events reworded.
"""

from __future__ import annotations

import dataclasses

import pytest

from cellguard.diagnose.diagnosis import diagnose
from cellguard.diagnose.recovery import attempts_of
from cellguard.record.reader import open_record
from cellguard.robot.recovery.outcome import RecoveryOutcome
from cellguard.runtime import run_scenario
from cellguard.scenario import parse_scenario

# as test_recovery_advice: no slip in the 5 acceptance cycles, slips in production cycles 5, 8 and 9
SCENARIO = {"cell": "arm-pick-place", "seed": 4, "acceptance_cycles": 5, "production_cycles": 6,
            "faults": [{"kind": "intermittent_slip", "rate": 0.4, "dx_mm": -5.0, "seed": 27}],
            "recovery": {"behaviours": [{"do": "retry_grasp", "trigger": "grasp_missed", "attempts": 2,
                                         "speed_scale": 0.7}]}}  # the gripper shuts at 1.8 s / 0.7 = 2.5714... s


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    folder = tmp_path_factory.mktemp("run") / "out"
    summary = run_scenario(parse_scenario(SCENARIO), folder)
    with open_record(folder) as record:
        cycles, events = list(record.cycles()), list(record.events())
        context = dict(record.context)
    return summary, cycles, events, context


def test_rewording_the_recovery_events_changes_no_attempt_and_no_finding(recorded):
    summary, cycles, events, context = recorded
    reworded = [dataclasses.replace(e, reason=f"Recovery step finished ({i})")
                if e.kind in ("recovery_start", "recovery_end") else e for i, e in enumerate(events)]
    assert sum(e.kind == "recovery_end" for e in reworded) == 6
    as_recorded, as_reworded = diagnose(cycles, events, context), diagnose(cycles, reworded, context)
    logged = [{"cycle": c["cycle"], **r} for c in summary["cycles"] for r in c.get("recovery_log", [])]
    assert [(r["cycle"], r["outcome"]) for r in logged] == [(5, "failed"), (5, "resumed"), (8, "failed"),
                                                            (8, "resumed"), (9, "failed"), (9, "resumed")]
    assert list(as_reworded.recoveries) == list(as_recorded.recoveries) == logged
    assert as_reworded.findings == as_recorded.findings and as_reworded.fixes == as_recorded.fixes
    slip = next(f for f in as_reworded.findings if f.cause == "tool_slip")
    assert "what got the cell running again: retry_grasp (3 of 3 cycles)" in slip.evidence


def test_an_event_reason_stays_the_words_of_its_logged_attempt(recorded):
    """The words are still written for people, from the same attempt the log holds."""
    summary, _, events, _ = recorded
    logged = [RecoveryOutcome.from_dict(r) for c in summary["cycles"] for r in c.get("recovery_log", [])]
    assert [e.reason for e in events if e.kind == "recovery_end"] == [done.reason() for done in logged]


def test_an_attempt_is_logged_and_carried_by_its_event_with_its_times_to_the_millisecond(recorded):
    """As its words have them: the log held the plan's raw close time (2.5714285714285716 s), so ``diagnose --json``
    of a record read from the log no longer said what it said when read from the words (2.571)."""
    summary = recorded[0]
    logged = [r for c in summary["cycles"] for r in c.get("recovery_log", [])]
    carried = [e["recovery"] for e in summary["events"] if e["kind"] == "recovery_end"]
    assert [r["close_s"] for r in logged] == [c["close_s"] for c in carried] == [2.571] * 6
    assert all(v == round(v, 3) for r in logged + carried for k, v in r.items() if k.endswith("_s") and v is not None)


@pytest.mark.parametrize("raw", [1.8 / 0.7, 1.8 / 0.3, 0.0005, 2.0004999, 12.3456789])
def test_the_times_of_an_older_records_log_read_as_its_words_gave_them(raw):
    """A record written before the log held its times to the millisecond reads as it did from the words."""
    entry = RecoveryOutcome("retry_grasp", "grasp_missed", 1, "failed", raw * 2, raw / 2, raw).to_dict()
    read = RecoveryOutcome.from_dict(entry)
    assert (read.duration_s, read.arrival_s, read.close_s) == tuple(float(f"{t:.3f}") for t in (raw * 2, raw / 2, raw))
    assert read == RecoveryOutcome.parse(RecoveryOutcome(**entry).reason())  # the words its run wrote


@pytest.mark.parametrize("entry", [None, "retry_grasp: attempt 1", {"behaviour": "retry_grasp"},
                                   {"behaviour": "b", "trigger": "t", "attempt": True, "outcome": "failed",
                                    "duration_s": 1.0},
                                   {"behaviour": "b", "trigger": "t", "attempt": 1, "outcome": "failed",
                                    "duration_s": float("nan")},
                                   {"behaviour": "b", "trigger": "t", "attempt": 1, "outcome": 3, "duration_s": 1.0},
                                   {"behaviour": "b", "trigger": "t", "attempt": 1, "outcome": "failed",
                                    "duration_s": 1.0, "close_s": "1.8"},
                                   {"behaviour": "b", "trigger": "t", "attempt": 1, "outcome": "failed",
                                    "duration_s": 10**400},  # no float holds it: OverflowError in the reader
                                   {"behaviour": "b", "trigger": "t", "attempt": 1, "outcome": "failed",
                                    "duration_s": 1.0, "close_s": -10**400},
                                   # an attempt no run writes: it read as one that fixed nothing
                                   {"behaviour": "b", "trigger": "t", "attempt": 1, "outcome": "fixed",
                                    "duration_s": 1.0},
                                   {"behaviour": "b", "trigger": "t", "attempt": 0, "outcome": "failed",
                                    "duration_s": 1.0},
                                   {"behaviour": "b", "trigger": "t", "attempt": 1, "outcome": "failed",
                                    "duration_s": -1.0},
                                   {"behaviour": "b", "trigger": "t", "attempt": 1, "outcome": "failed",
                                    "duration_s": 1.0, "arrival_s": -0.5, "close_s": 0.5}])
def test_a_log_entry_that_is_not_a_whole_attempt_is_left_out(entry):
    """A damaged or crafted record: the entry is left out, as the reader leaves out a malformed message; the
    whole attempt beside it still reads."""
    whole = RecoveryOutcome("retry_grasp", "grasp_missed", 2, "resumed", 3.25, 1.5, 1.8)
    rows = [{"cycle": 7, "features": {}, "outcome": {"recovery_log": [entry, whole.to_dict()]}},
            {"cycle": 3, "features": {}, "outcome": {"recovery_log": entry}}]
    assert attempts_of(rows) == [(7, whole)]


@pytest.mark.parametrize("words", ["b: attempt 0 after t, 1.000 s; outcome failed",
                                   "b: attempt 1 after t, 1.000 s; outcome fixed"])
def test_an_older_records_words_of_no_attempt_a_run_writes_are_left_out(words):
    assert RecoveryOutcome.parse(words) is None
    assert RecoveryOutcome.parse(words.replace("attempt 0", "attempt 1").replace("fixed", "failed")) is not None


def test_a_records_events_stay_hashable_with_their_recovery_fields(recorded):
    """``recovery`` is a dict: as a hashed field it made every event of a new record unhashable (``set`` raised)."""
    events = recorded[2]
    ended = [e for e in events if e.kind == "recovery_end"]
    assert ended and all(isinstance(e.recovery, dict) for e in ended)
    assert len(set(events)) == len(events)
    other = dataclasses.replace(ended[0], recovery={**ended[0].recovery, "outcome": "other"})
    assert other != ended[0] and other not in set(events)  # still told apart by the fields
