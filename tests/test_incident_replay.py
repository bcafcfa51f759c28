"""Incident replay: a recorded friction fault's cycle re-run in the simulator; --vary finds the factor."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from cellguard.calibrate.replay import replay
from cellguard.cli import app
from cellguard.runtime.loop import run_scenario
from cellguard.scenario import Scenario

FACTOR = 1.4
runner = CliRunner()


@pytest.fixture(scope="module")
def faulted(tmp_path_factory):
    """A production record (50 Hz ticks, chunks) whose cycle 1 has elbow friction x1.4."""
    scenario = Scenario.model_validate({"cell": "arm-pick-place", "seed": 3, "acceptance_cycles": 1,
                                        "production_cycles": 1, "faults": [
                                            {"kind": "friction_step", "joint": "elbow", "at_cycle": 1,
                                             "factor": FACTOR}]})
    out = tmp_path_factory.mktemp("incident") / "run"
    run_scenario(scenario, out)
    return out


def test_replay_reproduces_a_fault_free_cycle(faulted):
    r = replay(faulted, 0, model="nominal").to_dict()
    m = r["mismatch"]
    assert r["ticks"] > 100  # the 50 Hz stream of one cycle
    moving = m["joints"].index("elbow")
    assert max(m["position_rms"][:4]) < 2e-3  # [rad]: the chunks through a fresh guard track as recorded
    assert m["current_nrmse"][moving] < 0.1


def test_vary_finds_the_injected_friction_factor(faulted, tmp_path):
    page = tmp_path / "replay.html"
    result = runner.invoke(app, ["replay", str(faulted), "--cycle", "1", "--model", "nominal", "--vary",
                                 "friction:elbow=0.8..2.0", "-o", str(page), "--json"])
    assert result.exit_code == 0, result.output
    d = json.loads(result.output)
    best = d["vary"]["best_factor"]
    assert best == pytest.approx(FACTOR, rel=0.15)
    tried = dict(map(tuple, d["vary"]["tried"]))
    assert tried[min(tried, key=lambda f: abs(f - 1.0))] > tried[best]  # the nominal friction reproduces it worse
    html = page.read_text()
    assert html.count("<svg") == 2 and "friction of elbow" in html


@pytest.mark.parametrize("args, words", [
    (["--cycle", "7"], "--cycle: 7 is not a finished cycle"),
    (["--cycle", "1", "--vary", "friction:knee=0.8..1.6"], "'knee' is not a joint"),
    (["--cycle", "1", "--vary", "mass:elbow=0.8..1.6"], "allowed: friction, damping, armature"),
    (["--cycle", "1", "--vary", "friction:elbow=1.6..0.8"], "0 < LOW < HIGH"),
    (["--cycle", "1", "--vary", "friction:elbow=1e-9..1e9"], "0 < LOW < HIGH"),  # the form is right: the range is not
    (["--cycle", "1", "--model", "ideal"], "--model: 'ideal'"),
])
def test_bad_replay_input_is_one_line_and_exit_2(faulted, args, words):
    result = runner.invoke(app, ["replay", str(faulted), *args])
    assert result.exit_code == 2 and words in result.output
    assert len(result.output.strip().splitlines()) == 1
    assert not list(faulted.glob("replay-*.html"))


@pytest.mark.parametrize("text, low, high", [("friction:elbow=8e-1..1.6", 0.8, 1.6),
                                             ("friction:elbow=.5..2.", 0.5, 2.0), ("friction:elbow=1...5", 1.0, 5.0)])
def test_a_vary_range_is_read_in_every_way_a_number_is_written(text, low, high):
    from cellguard.calibrate.replay import parse_vary
    from cellguard.robot.registry import make_cell

    vary = parse_vary(text, make_cell("arm-pick-place"))
    assert (vary.parameter, vary.joint, vary.low, vary.high) == ("friction", "elbow", low, high)
