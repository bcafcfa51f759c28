"""Diagnose keeps the record's own placing of an event in no cycle.

The recorder stamps an event raised after a cycle's end marker with no cycle, even at the end's own time (the retreat's
first event lies there). Diagnose placed every unstamped event by time, spans closed, so a stop raised at that instant,
after the end, marked the finished cycle cut short and left it out of the monitors.
"""

from __future__ import annotations

import json

from record_synth import away_from_home_run, rewrite
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.record.reader import open_record


def test_a_stop_after_a_cycles_end_at_its_end_time_does_not_cut_it_short(tmp_path):
    run = away_from_home_run(tmp_path, 5, 2)
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
