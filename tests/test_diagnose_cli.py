"""`cellguard diagnose` and `cellguard report` on a real record written by `cellguard run`."""

from __future__ import annotations

import json

import pytest
import yaml
from typer.testing import CliRunner

from cellguard.cli import app

runner = CliRunner()


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    folder = tmp_path_factory.mktemp("run")
    scenario = folder / "scenario.yaml"
    scenario.write_text(yaml.safe_dump({"cell": "arm-pick-place", "seed": 3, "acceptance_cycles": 6,
                                        "production_cycles": 4,
                                        "faults": [{"kind": "fixture_shift", "at_cycle": 7, "dx_mm": 4.0}]}))
    out = folder / "out"
    result = runner.invoke(app, ["run", str(scenario), "--out", str(out), "--json"])
    assert result.exit_code == 0, result.output
    return out


def test_diagnose_json_reads_the_record_and_keeps_the_baseline(recorded):
    result = runner.invoke(app, ["diagnose", str(recorded), "--json"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.stdout)
    assert data["cycles"] == 10 and data["baseline_cycles"] == 6
    assert data["findings"][0]["cause"] == "fixture_shift" and data["first_faulted_cycle"] == 7
    assert data["last_good_cycle"] == 6 and data["drift_alarms"][0]["cycle"] >= 7
    assert (recorded / "baseline.json").is_file()
    again = json.loads(runner.invoke(app, ["diagnose", str(recorded), "--json"]).stdout)
    assert again["findings"] == data["findings"]  # the stored baseline gives the same answer


def test_report_writes_one_html_file_with_the_overlay_from_ticks(recorded, tmp_path):
    out = tmp_path / "r.html"
    result = runner.invoke(app, ["report", str(recorded), "-o", str(out)])
    assert result.exit_code == 0, result.output
    page = out.read_text()
    assert 'id="plot-overlay"><svg' in page and "fixture_shift" in page
    assert "No tick data" not in page  # the record's ticks were drawn


def test_the_report_of_a_cut_record_says_at_the_top_that_it_is_not_whole(recorded, tmp_path):
    """The page of a truncated record read as whole (only stderr said what was lost)."""
    cut = tmp_path / "cut"
    cut.mkdir()
    data = (recorded / "record.mcap").read_bytes()
    (cut / "record.mcap").write_bytes(data[: len(data) * 3 // 4])
    result = runner.invoke(app, ["report", str(cut), "-o", str(tmp_path / "cut.html")])
    assert result.exit_code == 1, result.output
    page = (tmp_path / "cut.html").read_text()
    assert '<div class=damaged id=record-damage>The record is not whole: truncated' in page
    whole = tmp_path / "whole.html"
    assert runner.invoke(app, ["report", str(recorded), "-o", str(whole)]).exit_code == 0
    assert "record-damage" not in whole.read_text()


def test_a_folder_without_a_record_is_one_line_and_exit_2(tmp_path):
    result = runner.invoke(app, ["diagnose", str(tmp_path / "nothing")])
    assert result.exit_code == 2
    assert result.output.strip().count("\n") == 0 and result.output.startswith("error:")


def test_a_baseline_from_another_robot_is_refused_and_kept(recorded, tmp_path):
    assert runner.invoke(app, ["diagnose", str(recorded), "--json"]).exit_code == 0
    stored = json.loads((recorded / "baseline.json").read_text())
    assert stored["bound_to"]["robot"] and stored["bound_to"]["profile_sha256"]
    other = tmp_path / "other"
    other.mkdir()
    for name in ("record.mcap", "baseline.json"):
        (other / name).write_bytes((recorded / name).read_bytes())
    stale = {**stored, "bound_to": {**stored["bound_to"], "robot": "another-robot"}}
    (other / "baseline.json").write_text(json.dumps(stale))
    before = (other / "baseline.json").read_bytes()
    result = runner.invoke(app, ["diagnose", str(other)])
    assert result.exit_code == 2 and "bound to robot 'another-robot'" in result.output
    assert result.output.strip().count("\n") == 0
    assert (other / "baseline.json").read_bytes() == before


def test_record_info_tells_a_calibration_from_the_dates_values_were_measured(recorded):
    """It printed 'calibrated 2026-10-14' for a profile that has no calibration (the dates of measured values)."""
    from cellguard.robot.registry import make_cell

    profile = make_cell("arm-pick-place").profile
    assert profile.calibration is None and profile.measured
    dates = ", ".join(sorted({m.measured for m in profile.measured}))
    result = runner.invoke(app, ["record", "info", str(recorded)])
    assert result.exit_code == 0, result.output
    assert f"calibration none; measured {dates}" in result.stdout and "calibrated" not in result.stdout
