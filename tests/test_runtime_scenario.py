"""The scenario's runtime keys (robot, cycle, realtime) are validated like the rest: one line naming the key."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import CellguardError, ScenarioError
from cellguard.record.reader import open_record
from cellguard.robot.bridges import make_bridge, parse_bridge
from cellguard.robot.bridges.sim_server import parse_address
from cellguard.runtime import Run
from cellguard.scenario import parse_scenario

BASE = {"cell": "arm-pick-place"}


@pytest.mark.parametrize("extra, key", [
    ({"realtime": {"inference": "gpu"}}, "realtime.inference"),
    ({"realtime": {"overrun_budget": -1}}, "realtime.overrun_budget"),
    ({"realtime": {"stale_s": 0}}, "realtime.stale_s"),
    ({"realtime": {"stop_category": 3}}, "realtime.stop_category"),
    ({"realtime": {"sleep": True}}, "realtime.sleep"),
    ({"cycle": {"source": "bell"}}, "cycle.source"),
    ({"cycle": {"seconds": 0}}, "cycle.seconds"),
    ({"cycle": {"source": "task", "seconds": 5}}, "cycle: Value error, seconds belongs to another source than 'task'"),
    ({"cycle": {"source": "home", "input": "x", "seconds": 5}}, "cycle: Value error, input, seconds belongs"),
    ({"robot": ""}, "robot"),
])
def test_bad_runtime_keys_are_refused_naming_the_key(extra, key):
    with pytest.raises(ScenarioError, match=key.replace(".", r"\.")):
        parse_scenario({**BASE, **extra})


def test_defaults_keep_a_plain_scenario_on_its_simulated_cell():
    sc = parse_scenario(BASE)
    assert sc.robot == "sim" and sc.cycle.source == "task" and sc.realtime.inference == "thread"


def test_an_unknown_bridge_scheme_lists_the_known_ones():
    with pytest.raises(CellguardError, match="unknown robot bridge 'ur-rtde'; known: .*sim-server"):
        make_bridge("ur-rtde:192.168.0.2", parse_scenario(BASE))
    with pytest.raises(ScenarioError, match="SCHEME:ARGUMENT"):
        parse_bridge("sim-server")


@given(st.text(max_size=40))
def test_any_sim_server_address_parses_to_loopback_or_is_refused_naming_the_key(text):
    try:
        host, port = parse_address(text)
    except ScenarioError as exc:
        assert str(exc).startswith("robot: sim-server address")
    else:
        assert host == "127.0.0.1" and 1 <= port <= 65535


def _cli_run(tmp_path, text: str, out):
    path = tmp_path / "s.yaml"
    path.write_text(text)
    return CliRunner().invoke(app, ["run", str(path), "--out", str(out)])


@pytest.mark.parametrize("text, message", [
    ("cell: arm-pick-place\ncycle: {source: policy}\n", "cycle.source: 'policy' needs a policy with episode_done()"),
    ("cell: quadruped-turns\ncycle: {source: home}\n", "cycle.source: 'home' needs a home pose"),
])
def test_a_cycle_source_the_robot_or_policy_cannot_serve_leaves_out_as_it_was(tmp_path, text, message):
    """Refused before the record starts: a partial record.mcap blocked the corrected scenario's --out."""
    result = _cli_run(tmp_path, text, tmp_path / "out")
    assert result.exit_code == 2 and result.stderr.startswith(f"error: {message}")
    assert result.stderr.count("\n") == 1 and not (tmp_path / "out").exists()
    (tmp_path / "kept").mkdir()
    (tmp_path / "kept" / "notes.txt").write_text("mine")
    assert _cli_run(tmp_path, text, tmp_path / "kept").exit_code == 2
    assert [p.name for p in (tmp_path / "kept").iterdir()] == ["notes.txt"]


def test_an_error_after_the_record_started_says_where_the_record_is_and_that_it_is_whole(tmp_path):
    """A start-up check refuses on the first chunk, after the record has started (a one-step chunk of 1 ms
    cannot cover the simulated 10 ms latency); the error line names the folder that keeps it. The record closed
    whole and holds the refusal: it was called partial and held only the watchdog's stop."""
    home = np.array([0.0, -0.3, 1.9, 1.55, 0.0, 0.025])
    np.savez(tmp_path / "short.npz", t=np.arange(0.0, 2.0, 0.05), actions=np.broadcast_to(home, (40, 1, 6)), dt=0.001)
    out = tmp_path / "out"
    result = _cli_run(tmp_path, f"cell: arm-pick-place\npolicy: replay:{tmp_path / 'short.npz'}\nacceptance_cycles: 1\n"
                                "production_cycles: 0\ncycle: {source: time, seconds: 1}\n", out)
    assert result.exit_code == 2, result.output
    assert result.stderr.startswith("error: start-up: inference latency")
    assert result.stderr.endswith(f"; the record in {out} is finished and whole; it has no summary.json\n")
    assert (out / "record.mcap").exists() and not (out / "summary.json").exists()
    with open_record(out) as rec:
        refused = [e.reason for e in rec.events() if e.kind == "startup_refused"]
    assert len(refused) == 1 and refused[0].startswith("start-up: inference latency")


def test_a_crash_after_the_record_started_says_where_the_record_is(tmp_path, monkeypatch):
    def crash(self, on_cycle=None):
        raise RuntimeError("a bug")

    monkeypatch.setattr(Run, "run_cycles", crash)
    out = tmp_path / "out"
    result = _cli_run(tmp_path, "cell: arm-pick-place\nacceptance_cycles: 1\nproduction_cycles: 0\n", out)
    assert isinstance(result.exception, RuntimeError)  # a bug keeps its traceback, after the line
    assert result.stderr == f"error: the record in {out} is finished and whole; it has no summary.json\n"
    assert (out / "record.mcap").exists()
