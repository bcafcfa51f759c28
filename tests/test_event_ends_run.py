"""Whether the run stops after an event is a property of its kind (``EventKind.ends_run``), not a list kept beside
the kinds: the LeRobot export leaves out a cycle one falls in as cut short, whichever of them it is."""

from __future__ import annotations

import pytest
from record_synth import record

from cellguard.control.events import EventKind
from cellguard.record.lerobot_export import export_lerobot
from cellguard.record.reader import open_record

# overrun_budget: the loop raises it as a robot link fault (runtime.loop _overrun); startup_refused: StartupRefused
# propagates out of the run. Not watchdog_no_first_chunk: a late first chunk starts the run, and a stop that removes
# a bridged robot's power ends it whatever asked the stop.
ENDING = {"operator_stop", "policy_lost", "record_failed", "run_process_lost", "robot_read_failed",
          "robot_read_timeout", "robot_state_stale", "robot_packets_dropped", "robot_write_failed",
          "robot_server_gone", "overrun_budget", "startup_refused"}
TICKS_PER_CYCLE = 200


def test_the_kinds_that_end_a_run():
    assert {kind.value for kind in EventKind if kind.ends_run} == ENDING
    assert not any(kind.ends_run for kind in EventKind if kind.routine)


@pytest.mark.parametrize("kind", [*sorted(ENDING), "limit_intervention"])
def test_a_cycle_an_ending_event_falls_in_is_cut_short(tmp_path, kind):
    record(tmp_path / "run", cycles=3, ticks_per_cycle=TICKS_PER_CYCLE, events={TICKS_PER_CYCLE + 50: kind})
    with open_record(tmp_path / "run") as rec:
        result = export_lerobot(rec, tmp_path / "dataset")
    if EventKind(kind).ends_run:
        assert result.episodes == (0, 2) and result.skipped == (f"cycle 1: cut short by {kind}",)
    else:
        assert result.episodes == (0, 1, 2) and not result.skipped
