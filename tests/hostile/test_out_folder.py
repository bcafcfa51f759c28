"""Class 8 (the parts on --out and baselines): a refused run prints one line and leaves no folder;
a run too short to be its own baseline says so; ``report`` takes ``--acceptance`` like ``diagnose``."""

from __future__ import annotations

import pytest

from .expect import refused, runner, snapshot
from .scenarios import run_refused, scenario_file
from cellguard.cli import app


def test_a_policy_refused_after_the_scenario_loads_prints_no_progress_and_leaves_no_folder(tmp_path):
    line = run_refused(tmp_path, scenario_file(tmp_path, policy=f"replay:{tmp_path / 'missing.npz'}"),
                       contains="no such file")
    assert "cycles" not in line


def test_a_fault_the_cell_cannot_simulate_leaves_no_folder(tmp_path):
    run_refused(tmp_path, scenario_file(tmp_path, faults=[{"kind": "servo_gain", "joint": "knee", "factor": 0.8}]),
                contains="faults[0].joint")


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """An acceptance run (5 cycles) and a production run with none, as a site would record them."""
    root = tmp_path_factory.mktemp("runs")
    acceptance = scenario_file(root, seed=3, acceptance_cycles=5, production_cycles=0)
    production = scenario_file(root, seed=4, acceptance_cycles=0, production_cycles=2)
    results = {}
    for name, path in (("acceptance", acceptance), ("production", production)):
        result = runner.invoke(app, ["run", str(path), "--out", str(root / name), "--json"])
        assert result.exit_code == 0, result.output
        results[name] = result
    return root, results


def test_a_short_acceptance_phase_is_a_warning_line(runs):
    _, results = runs
    assert "warning" not in results["acceptance"].stderr
    warnings = [line for line in results["production"].stderr.splitlines() if line.startswith("warning:")]
    assert len(warnings) == 1 and "acceptance_cycles: 0" in warnings[0] and "--acceptance" in warnings[0]


def test_report_takes_the_baseline_from_another_record(runs, tmp_path):
    root, _ = runs
    before = snapshot(root / "acceptance")
    refused(["report", root / "production", "-o", tmp_path / "r.html"], contains="at least 5 acceptance cycles")
    assert not (tmp_path / "r.html").exists()
    result = runner.invoke(app, ["report", str(root / "production"), "-o", str(tmp_path / "r.html"),
                                 "--acceptance", str(root / "acceptance")])
    assert result.exit_code == 0, result.output
    assert "<html" in (tmp_path / "r.html").read_text()
    assert snapshot(root / "acceptance") == before  # the acceptance record is read, never written


def test_escape_codes_in_a_records_site_are_never_printed_raw(tmp_path):
    """A record written elsewhere (not through a scenario, which refuses them) with escape codes in its text."""
    from record_synth import DT_NS, JOINTS, context, tick

    from cellguard.control.events import Event
    from cellguard.record.writer import RecordConfig, Recorder

    hostile = "plant\x1b[2J\x1b]0;owned\x07\nsecond line"
    rec = Recorder.create(tmp_path / "run", joints=JOINTS, dt_ns=DT_NS, context=context(site=hostile),
                          config=RecordConfig(), epoch_wall_ns=1_790_000_000_000_000_000)
    rec.cycle_begin(0, "acceptance", 0)
    for k in range(200):
        tick(rec, k, 0)
    rec.event(Event(100 * DT_NS, "protective_stop", hostile, category=2), 0)
    rec.cycle_end({"cycle": 0, "phase": "acceptance", "success": True, "features": {}}, 200 * DT_NS)
    rec.close()
    result = runner.invoke(app, ["record", "info", str(tmp_path / "run")])
    assert result.exit_code == 0, result.output
    assert "\x1b" not in result.output and "\x07" not in result.output
    assert "plant\\x1b[2J" in result.stdout
    assert not any(line.startswith("second line") for line in result.stdout.splitlines())  # the newline is escaped too
