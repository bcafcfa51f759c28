"""A SIGTERM after the run's last cycle: the record and the summary agree on it. Still open, the record takes the
``operator_stop`` event; once closed, the summary says the stop came after the record closed with every cycle run
(``stopped_after_record``), and the exit code is the operator's (130) either way. The probe's SIGTERM, 7.4 s into a
1 + 1 cycle run, made the summary and the exit code say "operator stop (SIGTERM)" over a record with no event of it.

The signal is sent from the run itself, at the moment at issue: a ``Run`` whose ``run_cycles`` (the record open) or
``close`` (called once the record has closed) raises it.
"""

from __future__ import annotations

import signal

import pytest
import typer

from cellguard.cli.errors import exit_if_stopped
from cellguard.record.reader import open_record
from cellguard.runtime import Run, run_scenario
from cellguard.scenario import parse_scenario

SCENARIO = {"cell": "arm-pick-place", "seed": 3, "policy": "scripted", "acceptance_cycles": 1, "production_cycles": 1}


class _SignalledAfterCycles(Run):
    """SIGTERM once every cycle (and the retreat) has run, the record still open."""

    def run_cycles(self, on_cycle=None) -> None:
        super().run_cycles(on_cycle)
        signal.raise_signal(signal.SIGTERM)


class _SignalledAfterRecord(Run):
    """SIGTERM as the run closes its policy and robot: after the record has closed."""

    def close(self) -> None:
        signal.raise_signal(signal.SIGTERM)
        super().close()


def _run(kind: type[Run], out):
    run = kind(parse_scenario(SCENARIO))
    summary = run_scenario(run.scenario, out, run=run)
    with open_record(out) as record:
        kinds = [e.kind for e in record.events()]
    with pytest.raises(typer.Exit) as exit_:
        exit_if_stopped(summary, out)
    return summary, kinds, exit_.value.exit_code


def test_a_sigterm_after_the_last_cycle_with_the_record_open_is_an_event_of_it(tmp_path):
    summary, kinds, code = _run(_SignalledAfterCycles, tmp_path / "out")
    assert summary["stopped"] == "operator stop (SIGTERM)" and "stopped_after_record" not in summary
    assert kinds.count("operator_stop") == 1 and code == 130, kinds
    event = next(e for e in summary["events"] if e["kind"] == "operator_stop")
    assert "after the run's motion had ended" in event["reason"]
    assert len(summary["cycles"]) == 2


def test_a_sigterm_once_the_record_closed_says_so_in_the_summary(tmp_path):
    summary, kinds, code = _run(_SignalledAfterRecord, tmp_path / "out")
    assert summary["stopped_after_record"] is True and "operator_stop" not in kinds
    assert summary["stopped"] == "operator stop (SIGTERM)"  # as before: a release's stage stops on it
    assert code == 130 and len(summary["cycles"]) == 2


class _StoppedThenSignalled(Run):
    """A run that ended stopped for its own cause with no stop event (its retreat not played), then a SIGTERM after
    its motion, the record still open."""

    def run_cycles(self, on_cycle=None) -> None:
        super().run_cycles(on_cycle)
        self.stopped = "the retreat home was not played: (the test's cause); the robot is held where it stopped"
        signal.raise_signal(signal.SIGTERM)


def test_a_sigterm_after_a_run_stopped_for_its_own_cause_writes_no_stop_into_its_record(tmp_path):
    """The record holds the run's stops: an ``operator_stop`` (category 2) after the run ended counted in a
    release's protective stops and could fail its hard gate."""
    run = _StoppedThenSignalled(parse_scenario(SCENARIO))
    summary = run_scenario(run.scenario, tmp_path / "out", run=run)
    with open_record(tmp_path / "out") as record:
        stops = [e.kind for e in record.events() if e.category is not None]
    assert stops == [] and summary["stopped"].startswith("the retreat home was not played"), stops
