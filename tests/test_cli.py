"""The command line: a short run writes its summary; bad input is one line and exit 2."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from cellguard.cli import app

runner = CliRunner()


def test_run_writes_summary_with_ground_truth_apart(tmp_path):
    scenario = tmp_path / "s.yaml"
    scenario.write_text("cell: arm-pick-place\nacceptance_cycles: 1\nproduction_cycles: 1\n"
                        "faults:\n  - {kind: fixture_shift, at_cycle: 1, dx_mm: 1.0}\n")
    result = runner.invoke(app, ["run", str(scenario), "--out", str(tmp_path / "out"), "--json"])
    assert result.exit_code == 0, result.output
    doc = json.loads(result.stdout.strip().splitlines()[-1])
    assert doc["phases"]["production"]["cycles"] == 1
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert [c["phase"] for c in summary["cycles"]] == ["acceptance", "production"]
    assert summary["ground_truth"]["faults"] == [{"kind": "fixture_shift", "at_cycle": 1, "dx_mm": 1.0, "dy_mm": 0.0}]
    assert "faults" not in summary["scenario"]
    assert len(summary["context"]["policy_sha256"]) == 64


def test_bad_scenario_is_one_line_and_exit_2(tmp_path):
    scenario = tmp_path / "s.yaml"
    scenario.write_text("cell: arm-pick-place\nproduction_cycles: lots\n")
    result = runner.invoke(app, ["run", str(scenario), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2
    assert result.stderr.strip().count("\n") == 0
    assert "production_cycles" in result.stderr
    assert not (tmp_path / "out").exists()


def test_embodiment_show_json():
    result = runner.invoke(app, ["embodiment", "show", "arm-pick-place", "--json"])
    assert result.exit_code == 0
    doc = json.loads(result.stdout)
    assert [j["name"] for j in doc["joints"]][:2] == ["shoulder_pan", "shoulder_lift"]
    assert doc["joints"][0]["velocity"] == 3.0


def test_unknown_cell_lists_known():
    result = runner.invoke(app, ["embodiment", "show", "lathe"])
    assert result.exit_code == 2
    assert "known: arm-pick-place" in result.stderr


def test_an_out_folder_that_cannot_be_made_is_one_line(tmp_path):
    scenario = tmp_path / "s.yaml"
    scenario.write_text("cell: arm-pick-place\nacceptance_cycles: 1\nproduction_cycles: 0\n")
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    result = runner.invoke(app, ["run", str(scenario), "--out", str(blocker / "out")])
    assert result.exit_code == 2
    assert result.stderr.startswith("error: --out ") and "cannot create the folder" in result.stderr


def test_a_stopped_run_names_its_cause_not_the_stop_that_carried_it_out(tmp_path, capsys):
    """The line named the last event with a stop category: the guard's protective stop or power_removed that
    carried out a lost-packets fault or a full disk, never the fault itself."""
    import typer

    from cellguard.cli.errors import exit_if_stopped

    events = [{"kind": "watchdog_stop", "category": 2, "t_ns": 1}, {"kind": "robot_packets_dropped", "category": 1,
              "t_ns": 5}, {"kind": "protective_stop", "category": 1, "t_ns": 5}, {"kind": "power_removed", "category": 1,
              "t_ns": 6}, {"kind": "retreat_aborted", "category": 2, "t_ns": 7}]
    with pytest.raises(typer.Exit) as ended:
        exit_if_stopped({"stopped": "robot link: robot_packets_dropped: 101 packets lost", "events": events}, tmp_path)
    assert ended.value.exit_code == 1
    assert capsys.readouterr().err.startswith("error: the cell was stopped (robot_packets_dropped): robot link")


def test_a_stopped_run_names_the_cause_its_stop_names_not_a_later_one(tmp_path, capsys):
    """A stale state stopped the run, then the server's silence became robot_server_gone: the line named the later."""
    import typer

    from cellguard.cli.errors import exit_if_stopped

    events = [{"kind": "robot_state_stale", "category": 1, "t_ns": 1}, {"kind": "protective_stop", "category": 1,
              "t_ns": 1}, {"kind": "robot_server_gone", "category": 1, "t_ns": 9}]
    with pytest.raises(typer.Exit):
        exit_if_stopped({"stopped": "robot link: robot_state_stale: 25 ms old", "events": events}, tmp_path)
    assert capsys.readouterr().err.startswith("error: the cell was stopped (robot_state_stale): robot link")


def test_an_operator_stop_whose_record_failed_does_not_call_it_complete(tmp_path, capsys):
    """Ctrl-C while a failed record closed: the line said the record was complete."""
    import typer

    from cellguard.cli.errors import exit_if_stopped

    with pytest.raises(typer.Exit) as ended:
        exit_if_stopped({"stopped": "operator stop (SIGINT)", "record_failed": "No space left on device",
                         "events": []}, tmp_path)
    assert ended.value.exit_code == 130
    err = capsys.readouterr().err
    assert "is not whole (No space left on device)" in err and "complete" not in err
