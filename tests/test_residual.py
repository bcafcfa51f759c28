"""The residual monitor on the simulated arm: a friction step names its joint, a payload names inertia/payload,
fault-free windows stay quiet, and diagnosis takes the alarm as evidence."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from cellguard.calibrate.residual import ResidualMonitor, watch
from cellguard.diagnose.cause import Finding
from cellguard.diagnose.from_record import diagnose_record
from cellguard.diagnose.residual import with_residual
from cellguard.runtime.loop import Run, run_scenario
from cellguard.scenario import Scenario

ARM = "arm-pick-place"
BASE = 5  # baseline windows in these tests (the monitor's default is ten)


@pytest.fixture(scope="module")
def friction_run(tmp_path_factory):
    """Five acceptance cycles, two quiet production cycles, then elbow friction x1.3 for two cycles; recorded."""
    scenario = Scenario.model_validate({"cell": ARM, "acceptance_cycles": BASE, "production_cycles": 4, "faults": [
        {"kind": "friction_step", "joint": "elbow", "at_cycle": BASE + 2, "factor": 1.3}]})
    run = Run(scenario)
    watch(run, ResidualMonitor(run.cell, baseline=BASE))
    windows = []
    out = tmp_path_factory.mktemp("residual") / "run"
    run_scenario(scenario, out, run=run, on_cycle=lambda o: windows.append(o["residual"]))
    return out, windows


def test_friction_step_alarms_within_two_windows_and_names_the_joint(friction_run):
    _, windows = friction_run
    assert all(w.get("baseline") for w in windows[:BASE])
    assert [w["alarms"] for w in windows[BASE:BASE + 2]] == [[], []]  # fault-free production: quiet
    alarms = [a for w in windows[BASE + 2:BASE + 4] for a in w["alarms"]]
    assert alarms, [w.get("cusum") for w in windows]
    first = alarms[0]
    assert first["joint"] == "elbow" and first["parameter"] == "friction"
    assert first["change"] == pytest.approx(0.3 * 0.2, rel=0.25)  # +30 % of 0.2 N*m
    assert {a["joint"] for a in alarms} == {"elbow"}
    assert "drifted beyond its model" in first["message"]


def test_the_alarm_is_in_the_record_and_diagnosis_takes_it(friction_run):
    out, _ = friction_run
    d = diagnose_record(out).to_dict()
    evidence = [(f["cause"], e) for f in d["findings"] for e in f["evidence"] if e.startswith("residual monitor")]
    assert evidence, d["findings"]
    cause, words = evidence[0]
    assert cause in ("friction", "model_drift") and "elbow" in words


def test_a_payload_change_names_inertia_payload_not_friction():
    run = Run(Scenario(cell=ARM, acceptance_cycles=BASE + 3, production_cycles=0))
    monitor = ResidualMonitor(run.cell, baseline=BASE)
    watch(run, monitor)
    windows = []
    try:
        for c in range(BASE + 3):
            if c == BASE:
                m = run.cell.model
                m.body_mass[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "tool")] += 0.2
            windows.append(run.cycle()["residual"])
    finally:
        run.close()
    alarms = [a for w in windows[BASE:] for a in w["alarms"]]
    assert alarms
    assert {a["parameter"] for a in alarms} == {"inertia/payload"}
    payload = [a["change"] for a in alarms if a["signature"] == "payload"]
    assert payload and np.median(payload) == pytest.approx(0.2, rel=0.25)


def test_with_residual_adds_evidence_to_a_matching_finding_else_model_drift():
    alarm = {"cycle": 12, "joint": "elbow", "parameter": "friction", "signature": "friction", "message": "m"}
    friction = Finding("friction", 11, 0.8, ("current up",), ("current_rms.elbow",), ("elbow",))
    merged = with_residual([friction], [alarm])
    assert len(merged) == 1 and merged[0].evidence[-1] == "residual monitor, cycle 12: m"
    other = with_residual([Finding("friction", 11, 0.8, ("x",), (), ("wrist_flex",))], [alarm])
    assert [f.cause for f in other] == ["friction", "model_drift"] and other[1].joints == ("elbow",)
    assert "`cellguard identify DIR --only elbow,friction`" in other[1].evidence[1]  # on an excitation record
    assert "cellguard excite CELL --seconds 20" in other[1].evidence[1]


def test_a_scenario_asks_for_the_monitor_and_cellguard_run_records_and_diagnoses_its_alarm(tmp_path):
    """``residual_monitor: true``: `cellguard run` watches every cycle (the acceptance cycles learn), the
    windows are in the record and an elbow friction step is named there and in the diagnosis."""
    from typer.testing import CliRunner

    from cellguard.cli import app
    from cellguard.record.reader import open_record

    scenario = tmp_path / "watched.yaml"
    scenario.write_text(f"cell: {ARM}\nacceptance_cycles: 10\nproduction_cycles: 3\nresidual_monitor: true\n"
                        "faults:\n  - {kind: friction_step, joint: elbow, at_cycle: 11, factor: 1.3}\n")
    result = CliRunner().invoke(app, ["run", str(scenario), "--out", str(tmp_path / "run"), "--json"])
    assert result.exit_code == 0, result.output
    with open_record(tmp_path / "run") as rec:
        windows = [c.outcome["residual"] for c in rec.cycles()]
    assert len(windows) == 13 and all(w.get("baseline") for w in windows[:10]) and not windows[10].get("baseline")
    alarms = [a for w in windows[11:] for a in w["alarms"]]
    assert alarms and {(a["joint"], a["parameter"]) for a in alarms} == {("elbow", "friction")}
    d = diagnose_record(tmp_path / "run").to_dict()
    assert any(e.startswith("residual monitor") and "elbow" in e for f in d["findings"] for e in f["evidence"])


def test_the_monitor_wants_ten_acceptance_cycles_and_says_so(tmp_path):
    from typer.testing import CliRunner

    from cellguard.cli import app

    scenario = tmp_path / "short.yaml"
    scenario.write_text(f"cell: {ARM}\nacceptance_cycles: 5\nproduction_cycles: 1\nresidual_monitor: true\n")
    result = CliRunner().invoke(app, ["run", str(scenario), "--out", str(tmp_path / "run"), "--json"])
    assert result.exit_code == 2
    assert "residual_monitor: needs acceptance_cycles >= 10" in result.output
    assert not (tmp_path / "run").exists()
