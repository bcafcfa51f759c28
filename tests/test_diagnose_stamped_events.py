"""Diagnose keeps the record's own placing of an event in no cycle.

The recorder stamps an event raised after a cycle's end marker with no cycle, even at the end's own time (the retreat's
first event lies there). Diagnose placed every unstamped event by time, spans closed, so a stop raised at that instant,
after the end, marked the finished cycle cut short and left it out of the monitors.
"""

from __future__ import annotations

import json

import numpy as np
from record_synth import rewrite
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.record.reader import open_record
from cellguard.robot.registry import make_cell
from cellguard.runtime import run_scenario
from cellguard.scenario import parse_scenario


def _away_from_home(folder):
    """A run whose policy leaves the arm away from home: its retreat begins at the last cycle's end."""
    home = np.array(make_cell("arm-pick-place").read().q, dtype=np.float64)
    t = np.arange(0.0, 3.0, 0.1)
    actions = np.array([[home + np.array([0.5 * (s + k * 0.02), 0, 0, 0, 0, 0]) for k in range(1, 26)] for s in t])
    np.savez(folder / "turn.npz", t=t, actions=actions, dt=np.float64(0.02))
    run_scenario(parse_scenario({"cell": "arm-pick-place", "policy": f"replay:{folder / 'turn.npz'}",
                                 "acceptance_cycles": 5, "production_cycles": 2,
                                 "cycle": {"source": "time", "seconds": 1.0}}), folder / "run")
    return folder / "run"


def test_a_stop_after_a_cycles_end_at_its_end_time_does_not_cut_it_short(tmp_path):
    run = _away_from_home(tmp_path)
    with open_record(run / "record.mcap") as rec:
        last = max(rec.cycle_spans().items())
        begin = [e for e in rec.events() if e.kind == "retreat_begin"]
    assert begin and begin[0].t_ns == last[1][1] and begin[0].cycle is None  # the case: after the end, at its time

    def stop(topic: str, d: dict) -> dict:
        if topic == "/events" and d.get("kind") == "retreat_begin":
            return {**d, "kind": "operator_stop", "category": 2, "reason": "SIGINT: read after the cycle's end"}
        return d

    rewrite(run, tmp_path / "b", edit=stop)
    result = CliRunner().invoke(app, ["diagnose", str(tmp_path / "b"), "--json"])
    d = json.loads(result.stdout)
    assert d["run_end"]["kind"] == "operator_stop" and d["run_end"]["cycle"] is None, d["run_end"]
    assert d["cut_short_cycles"]["cycles"] == [], d["cut_short_cycles"]
