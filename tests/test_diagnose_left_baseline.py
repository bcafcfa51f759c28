"""The acceptance baseline, items left open: how many cycles a mirrored cell needs, a baseline.json without its
source, and a step in acceptance told as a step."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_diagnose_probe41_acceptance import _rows as stepped_rows
from test_diagnose_trend import _rows as ramp_rows
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.cli.diagnose import warn_if_unsteady
from cellguard.diagnose import Baseline, as_cycles, diagnose
from cellguard.errors import RecordError
from cellguard.runtime import Run
from cellguard.scenario import parse_scenario
from record_synth import record


def _turns(n: int, step_at: int | None = None) -> list[dict]:
    """``n`` acceptance cycles of a cell that alternates left and right turns (left on even cycles), a current with
    0.1 % noise that steps +5 % from cycle ``step_at``."""
    rng = np.random.default_rng(4)
    return [{"cycle": i, "phase": "acceptance", "success": True, "direction": "left" if i % 2 == 0 else "right",
             "features": {"current_rms.fl_knee": 1.2 * (1 + 1e-3 * rng.standard_normal())
                          * (1.05 if step_at is not None and i >= step_at else 1.0)}}
            for i in range(n)]


# -- 1. a mirrored cell needs 5 acceptance cycles of each motion -------------------------------------------------
def test_an_acceptance_short_of_one_motion_says_how_many_cycles_the_run_needs():
    """Nine alternating cycles are 5 left and 4 right turns: the refusal said only "got 4", not that such a cell
    needs 10 acceptance cycles in all (the number to put in the scenario)."""
    with pytest.raises(RecordError) as caught:
        Baseline.from_cycles(as_cycles(_turns(9)))
    said = str(caught.value)
    assert "motion 'right', got 4 (of the 9: left 5, right 4)" in said
    assert "at least 10 acceptance cycles where they alternate" in said
    for n in (10, 12):
        assert {k: m.n for k, m in Baseline.from_cycles(as_cycles(_turns(n))).motions.items()} == {"left": n // 2,
                                                                                                "right": n // 2}


def test_a_clean_quadruped_run_of_12_acceptance_cycles_builds_its_own_baseline():
    """The case reported: seed 2, 12 acceptance cycles, no fault: 6 left and 6 right turns, a baseline of each."""
    run = Run(parse_scenario({"cell": "quadruped-turns", "seed": 2, "acceptance_cycles": 12, "production_cycles": 1}))
    rows = [run.cycle() for _ in range(13)]
    run.close()
    d = diagnose(rows, [], {})
    assert {k: m.n for k, m in d.baseline.motions.items()} == {"left": 6, "right": 6}


# -- 2. a baseline.json without a source ---------------------------------------------------------------------------
def test_a_baseline_json_without_its_source_is_refused_and_kept(tmp_path):
    """Read as "stored baseline", it was taken for another record's acceptance: this record's acceptance cycles were
    watched against themselves, and an older one of its own was never taken again. Every cellguard writes the source;
    a file without one was edited: one line, exit 2, the file left as it is."""
    record(tmp_path / "run", 20, 3)
    assert CliRunner().invoke(app, ["diagnose", str(tmp_path / "run")]).exit_code in (0, 1)
    path = tmp_path / "run" / "baseline.json"
    stored = json.loads(path.read_text())
    assert stored["source"] == "acceptance cycles of this record"
    del stored["source"]
    path.write_text(json.dumps(stored))
    result = CliRunner().invoke(app, ["diagnose", str(tmp_path / "run")])
    assert result.exit_code == 2, result.output
    assert f"{path}: baseline: malformed: the file has no source" in " ".join(result.output.split())
    assert json.loads(path.read_text()) == stored


# -- 3. a step in acceptance is told as a step, with its cycle and feature -----------------------------------------
def test_a_step_in_acceptance_is_warned_as_a_step_at_its_cycle(tmp_path, capsys):
    d = diagnose(stepped_rows(5, seed=2), [], {})
    assert d.baseline.steps == {"tracking_max.elbow_flex": 5, "tracking_rms.elbow_flex": 5}
    warn_if_unsteady(d.baseline)
    said = " ".join(capsys.readouterr().err.split())
    assert "tracking_rms.elbow_flex stepped +3.0 % at cycle 5" in said
    d.baseline.save(tmp_path / "baseline.json")
    assert Baseline.load(tmp_path / "baseline.json").steps == d.baseline.steps
    ramp = diagnose(ramp_rows(0.007), [], {}).baseline
    assert ramp.steps == {}
    warn_if_unsteady(ramp)
    assert "current_rms.elbow trended +6.1 %" in " ".join(capsys.readouterr().err.split())


def test_a_step_of_one_motion_is_dated_at_its_cycle_of_the_record():
    """On a mirrored cell the step is found among one motion's cycles (every other one): its cycle is the record's."""
    baseline = Baseline.from_cycles(as_cycles(_turns(20, step_at=10)))
    assert baseline.steps == {"current_rms.fl_knee": 10}


def test_a_run_short_of_one_motion_warns_at_its_end(tmp_path):
    """``run`` of the quadruped with 5 acceptance cycles (3 left, 2 right turns) warned nothing (5 was enough in
    all), and diagnose then refused it: now its last line says so, in diagnose's words."""
    scenario = tmp_path / "q.yaml"
    scenario.write_text("cell: quadruped-turns\npolicy: scripted\npolicy_hz: 20\nacceptance_cycles: 5\n"
                        "production_cycles: 0\n")
    result = CliRunner().invoke(app, ["run", str(scenario), "--out", str(tmp_path / "run")])
    assert result.exit_code == 0, result.output
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("warning: baseline: needs at least 5 acceptance cycles of motion 'left', got 3 (of the 5: "
                           "left 3, right 2)")
    assert "at least 10 acceptance cycles" in last and last.endswith("--acceptance OTHER_RUN")


def test_a_clean_step_half_way_is_told_as_a_step_not_a_steeper_trend():
    """A 5 % step at any split of 10 or 20 cycles (0.1 % noise) is a step at its cycle: told by size, a step half way
    read as a trend of +5.5 % (the line through it is steeper than the step), with no cycle."""
    from cellguard.diagnose import steady

    for n in (10, 20):
        for at in range(steady.SIDE, n - steady.SIDE + 1):
            rng = np.random.default_rng(at)
            x = (1.2 * (1 + 1e-3 * rng.standard_normal(n)) * np.where(np.arange(n) >= at, 1.05, 1.0))[:, None]
            moved = steady.trends(["current_rms.elbow"], x)["current_rms.elbow"]
            assert moved.step_at == at and abs(moved.change / 0.06 - 1.0) < 0.05, (n, at, moved)


def test_a_ramp_is_still_told_as_a_trend():
    from cellguard.diagnose import steady

    rng = np.random.default_rng(3)
    x = (1.2 * (1 + 1e-3 * rng.standard_normal(20)) * (1 + 0.003 * np.arange(20)))[:, None]
    assert steady.trends(["current_rms.elbow"], x)["current_rms.elbow"].step_at is None


def test_a_baseline_json_written_before_steps_tells_neither_step_nor_trend(tmp_path, capsys):
    """Such a file cannot say whether its acceptance stepped: "trended" claimed what it does not know."""
    d = diagnose(stepped_rows(5, seed=2), [], {})
    d.baseline.save(tmp_path / "baseline.json")
    stored = json.loads((tmp_path / "baseline.json").read_text())
    del stored["steps"]
    (tmp_path / "baseline.json").write_text(json.dumps(stored))
    old = Baseline.load(tmp_path / "baseline.json")
    assert old.steps is None
    warn_if_unsteady(old)
    said = " ".join(capsys.readouterr().err.split())
    assert "tracking_rms.elbow_flex +3.0 % over" in said and "trended" not in said and "stepped" not in said


@pytest.mark.parametrize("steps, why", [
    (0, "steps must be an object"), ([], "steps must be an object"), (False, "steps must be an object"),
    ({"current_rms.nowhere": 5}, "steps.current_rms.nowhere is not among the trends"),
    ({"tracking_rms.elbow_flex": 0}, "steps.tracking_rms.elbow_flex must be a whole number of at least 3"),
    ({"tracking_rms.elbow_flex": 9}, "steps.tracking_rms.elbow_flex must be at most 7")])
def test_a_baseline_json_with_impossible_steps_is_refused_naming_them(tmp_path, steps, why):
    """A step needs 3 acceptance cycles on either side; anything but an object of the trends' features was read as
    no steps."""
    d = diagnose(stepped_rows(5, seed=2), [], {})
    d.baseline.save(tmp_path / "baseline.json")
    stored = json.loads((tmp_path / "baseline.json").read_text())
    stored["steps"] = steps
    (tmp_path / "baseline.json").write_text(json.dumps(stored))
    with pytest.raises(RecordError) as caught:
        Baseline.load(tmp_path / "baseline.json")
    assert why in str(caught.value)
