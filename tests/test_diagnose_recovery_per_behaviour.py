"""A recovery attempt is late only against the acceptance attempts of its own behaviour and trigger, and a cycle that
failed its task is no last good cycle.

A cell whose slip the retry could not fix escalated every cycle, acceptance and production alike, from
``retry_grasp`` (contact at 1.6 s) to ``back_off`` (half speed: 3.2 s); read against the median of both, every
production ``back_off`` was "late", named ``recovery`` ("a speed scaling of the recovery") with a failed cycle called
last good.
"""

from __future__ import annotations

import json

import numpy as np
import yaml
from test_diagnosis_rules import GEOMETRY
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.cli.diagnose import print_diagnosis
from cellguard.diagnose import diagnose
from cellguard.diagnose.cycles import Cycle
from cellguard.diagnose.recovery import attempts_of, recovery_finding
from cellguard.robot.recovery.outcome import RecoveryOutcome

RETRY = ("retry_grasp", "grasp_missed")
BACK_OFF = ("back_off", "escalation from retry_grasp")


def _attempt(kind, outcome, arrival, close):
    return RecoveryOutcome(*kind, 1, outcome, 4.0, arrival, close)


def _read(cycles, by_cycle):
    """The cycles and their attempts as the diagnosis reads them: from each row's recovery_log."""
    rows = [{"cycle": c.index, "features": {}, "recovery_log": [o.to_dict() for o in by_cycle.get(c.index, ())]}
            for c in cycles]
    return attempts_of(rows)


def _cycles(acceptance, production, success=True):
    return ([Cycle(i, "acceptance", success, {}) for i in range(acceptance)]
            + [Cycle(i, "production", success, {}) for i in range(acceptance, acceptance + production)])


def test_a_slower_behaviour_escalated_to_every_cycle_is_not_a_late_recovery():
    cycles = _cycles(5, 3, success=False)
    every = [_attempt(RETRY, "escalated", 1.595, 1.8), _attempt(BACK_OFF, "gave_up", 3.161, 3.6)]
    assert recovery_finding(cycles, _read(cycles, {c.index: every for c in cycles})) is None


def test_an_attempt_is_read_against_its_own_behaviours_acceptance_pace():
    """Pooled with four slower back_offs (2.4 s) the acceptance median hid a retry that took twice its own 1.0 s."""
    cycles = _cycles(6, 2)
    by_cycle = {i: [_attempt(RETRY, "resumed", 1.0, 2.5)] for i in (0, 1)}
    by_cycle |= {i: [_attempt(BACK_OFF, "resumed", 2.4, 3.0)] for i in (2, 3, 4, 5)}
    by_cycle |= {i: [_attempt(RETRY, "resumed", 2.0, 2.5)] for i in (6, 7)}
    found = recovery_finding(cycles, _read(cycles, by_cycle))
    assert found is not None and found.cycle == 6
    assert found.evidence[0] == ("2 recovery attempts from cycle 6 on arrived at contact 2.00 s after they started "
                                 "(median) vs 1.00 s for the 2 acceptance recoveries (retry_grasp after grasp_missed)")


def test_an_attempt_cut_off_before_it_arrived_is_not_late_one_that_ran_out_without_arriving_is():
    """A stop or the cycle's end that cut an attempt before its contact says nothing of its pace."""
    cycles = _cycles(3, 3)
    accepted = {i: [_attempt(RETRY, "resumed", 1.6, 1.8)] for i in range(3)}
    cut = {i: [_attempt(RETRY, "cut_off", None, 1.8)] for i in (3, 4, 5)}
    assert recovery_finding(cycles, _read(cycles, accepted | cut)) is None
    ran_out = {i: [_attempt(RETRY, "gave_up", None, 1.8)] for i in (3, 4, 5)}
    found = recovery_finding(cycles, _read(cycles, accepted | ran_out))
    assert found is not None and "3 recovery attempts from cycle 3 on arrived at contact never" in found.evidence[0]


def _shifted(failed) -> list[dict]:
    """Geometry rows, the fixture moved 1 mm in y at cycle 25 (acceptance 0-19); cycles ``failed`` missed their pick."""
    rng = np.random.default_rng(5)
    rows = []
    for i in range(30):
        f = {k: v + 0.02 * rng.standard_normal() for k, v in {**GEOMETRY, "place_error_mm": 0.5}.items()}
        for k in ("part_seen_y_mm", "fixture_seen_y_mm", "grasp_tcp_y_mm"):
            f[k] += 1.0 if i >= 25 else 0.0
        rows.append({"cycle": i, "phase": "acceptance" if i < 20 else "production", "success": i not in failed,
                     "features": f})
    return rows


def test_a_cycle_that_failed_its_task_is_not_the_last_good_one():
    d = diagnose(_shifted(failed={24}), [], {})
    assert [(f.cause, f.cycle) for f in d.findings] == [("fixture_shift", 25)], [f.to_dict() for f in d.findings]
    assert (d.last_good_cycle, d.first_faulted_cycle) == (23, 25)


def test_with_no_good_cycle_before_the_fault_the_text_says_so(capsys):
    """It printed "last good cycle None" (a fault from a record's first cycle, or a cell that never did its task)."""
    d = diagnose(_shifted(failed=set(range(25))), [], {})
    assert (d.last_good_cycle, d.first_faulted_cycle) == (None, 25)
    print_diagnosis(d)
    head = " ".join(capsys.readouterr().out.split("  fixture_shift")[0].split())
    assert head.endswith("drift alarm(s), first faulted cycle 25 (no good cycle before it)") and "None" not in head


def test_a_run_that_escalates_to_back_off_every_cycle_has_no_recovery_finding(tmp_path):
    """The probe's run (every cycle alike, all failed, no speed override) was named ``recovery`` from cycle 5 with
    "last good cycle 4"."""
    scenario = tmp_path / "L.yaml"
    scenario.write_text(yaml.safe_dump({
        "cell": "arm-pick-place", "acceptance_cycles": 5, "production_cycles": 3,
        "faults": [{"kind": "intermittent_slip", "rate": 1.0, "dx_mm": -5.0}],
        "recovery": {"behaviours": [{"do": "retry_grasp", "trigger": "grasp_missed", "attempts": 1,
                                     "then": "back_off"}, {"do": "back_off"}]}}))
    run = CliRunner().invoke(app, ["run", str(scenario), "--out", str(tmp_path / "run")])
    assert run.exit_code == 0, run.output
    result = CliRunner().invoke(app, ["diagnose", str(tmp_path / "run"), "--json"])
    assert result.exit_code == 0, result.output
    d = json.loads(result.stdout)
    assert {r["behaviour"] for r in d["recoveries"]} == {"retry_grasp", "back_off"} and len(d["recoveries"]) == 16
    assert d["findings"] == [] and d["last_good_cycle"] is None and d["first_faulted_cycle"] is None


def test_the_report_says_so_too(tmp_path):
    """The report page read "Last good cycle None"."""
    from cellguard.report.html import _last_good

    d = diagnose(_shifted(failed=set(range(25))), [], {})
    page = _last_good(d, None)
    assert "First faulted cycle <b>25</b> (no good cycle before it)" in page and "None" not in page


def test_late_attempts_of_two_kinds_are_each_told_against_their_own():
    """Pooled, the evidence quoted a median arrival (2.79 s) and close (2.70 s) that no attempt had, between a retry's
    1.87 s and a back_off's 3.71 s."""
    cycles = _cycles(6, 3)
    by_cycle = {i: [_attempt(RETRY, "escalated", 1.0, 1.2), _attempt(BACK_OFF, "resumed", 2.4, 3.0)] for i in range(6)}
    by_cycle |= {i: [_attempt(RETRY, "escalated", 2.0, 1.2), _attempt(BACK_OFF, "resumed", 4.0, 3.0)]
                 for i in (6, 7, 8)}
    found = recovery_finding(cycles, _read(cycles, by_cycle))
    assert found is not None and found.cycle == 6
    assert found.evidence[0] == (
        "6 recovery attempts from cycle 6 on arrived at contact: 3 of back_off 4.00 s after they started (median) vs "
        "2.40 s for the 6 acceptance recoveries (back_off after escalation from retry_grasp); 3 of retry_grasp 2.00 s "
        "after they started (median) vs 1.00 s for the 6 acceptance recoveries (retry_grasp after grasp_missed)")
    assert found.evidence[1] == ("their gripper was told to shut at 3.00 s, 1.00 s before the arm arrived (back_off); "
                                 "1.20 s, 0.80 s before the arm arrived (retry_grasp): the fingers closed above the part")
