"""A robot link lost mid-cycle under ``realtime.stop_category: 2`` removes power at once, as category 1 does.

A category 2 stop is a controlled stop with power kept: the loop brakes the robot by its commands and holds it
there, and both need the link. The cycle ended on the link's category 2 event with no guard stop at all, the
drives still powered, of a robot the loop could no longer command. Against a real ``cellguard sim-server``
killed mid-cycle, as ``test_sim_server.py`` kills it.
"""

from __future__ import annotations

import threading
import time

from sim_server_util import scenario, server_counters, start_server, sway_file

from cellguard.record.reader import open_record
from cellguard.runtime import Run, run_scenario
from cellguard.scenario import parse_scenario


def test_a_link_lost_under_category_2_removes_power_at_once_naming_why(tmp_path):
    proc, port = start_server()
    try:
        def kill():  # mid-cycle: once the loop has commanded for 0.3 s
            while server_counters(port).get("commands", 0) < 300:
                time.sleep(0.01)
            proc.kill()

        threading.Thread(target=kill, daemon=True).start()
        run = Run(parse_scenario(scenario(port, sway_file(tmp_path / "sway.npz"), stop_category=2)))
        summary = run_scenario(run.scenario, tmp_path / "out", run=run)
    finally:
        proc.kill()
        proc.wait()
    events = summary["events"]
    link = [e for e in events if e["kind"] in ("robot_read_timeout", "robot_server_gone")]
    assert link and link[0]["category"] == 2, events  # the scenario's category, as the link asked it
    assert summary["stopped"].startswith("robot link") and not run.guard.power
    stops = [e for e in events if e["kind"] == "protective_stop"]
    removed = [e for e in events if e["kind"] == "power_removed"]
    assert [e["category"] for e in stops] == [0] and [e["category"] for e in removed] == [0], events
    why = "robot link lost, " + run.link.reason + "; the category 2 stop cannot be commanded without it"
    assert why in stops[0]["reason"] and why in removed[0]["reason"]
    assert link[0]["t_ns"] <= stops[0]["t_ns"] == removed[0]["t_ns"]  # on the tick the link was found lost
    with open_record(tmp_path / "out") as record:
        kinds = [e.kind for e in record.events()]
    assert {link[0]["kind"], "protective_stop", "power_removed"} <= set(kinds)
