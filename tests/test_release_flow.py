"""The whole path on the arm cell: a release through every stage, then a production failure that
rolls back to last_good, recorded in the next run's context; the release page."""

from __future__ import annotations

import json

import pytest
from release_helpers import CELL, cli, write_plan

from cellguard.record.reader import open_record

pytestmark = pytest.mark.slow

STAGES = {
    "sim": {"runs": [{"name": "fixture-minus-1mm", "seed": 6, "acceptance_cycles": 2,
                      "faults": [{"kind": "fixture_shift", "at_cycle": 0, "dx_mm": -1.0}]}],
            "gates": [{"metric": "success_rate", "min": 1.0, "min_cycles": 2},
                      {"metric": "protective_stops", "max": 0}, {"metric": "limit_violations", "max": 0}]},
    "bench": {"clock": "wall", "runs": [{"name": "bench", "seed": 8, "acceptance_cycles": 1,
                                         # a shared CI machine is no real-time host: overruns are counted, not a stop
                                         "realtime": {"overrun_budget": 1_000_000}}],
              "gates": [{"metric": "success_rate", "min": 1.0}, {"metric": "inference_latency_p99_ms", "max": 500}]},
    "pilot": {"shadow": True, "runs": [{"name": "shadow", "seed": 9, "acceptance_cycles": 1}],
              "gates": [{"metric": "shadow_distance_p95_mrad", "max": 30}, {"metric": "shadow_would_stop", "max": 0},
                        {"metric": "shadow_would_clamp", "max": 0.05}]},
    "production": {"runs": [{"name": "shift", "seed": 10, "acceptance_cycles": 2}],
                   "gates": [{"metric": "success_rate", "min": 0.95, "min_cycles": 2},
                             {"metric": "protective_stops", "max": 0}]},
}


def _through_every_stage(site, plan, note: str, last_run: str = "production") -> str:
    made = cli("create", "--policy", "scripted", "--profile", CELL, "--note", note, "--site", str(site), "--json")
    rid = json.loads(made.stdout)["id"]
    for stage in STAGES:
        promoted = cli("promote", rid, "--cell", CELL, "--to", stage, "--plan", str(plan), "--site", str(site))
        assert promoted.exit_code == 0, promoted.output
        result = cli("run", "--cell", CELL, "--stage", stage, "--plan", str(plan), "--site", str(site), "--json")
        assert result.exit_code == 0, result.output
        assert json.loads(result.stdout)["verdict"] == "pass"
        if stage == last_run:
            break
    return rid


def test_a_production_failure_rolls_back_to_last_good_and_the_next_run_records_it(tmp_path):
    site = tmp_path / "site"
    site.mkdir()
    plan = write_plan(site / "release-plan.yaml", STAGES)  # the plan in force: last_good is taken under it
    first = _through_every_stage(site, plan, "v1")
    # a second release passes sim, bench and the pilot (in shadow beside the first, which drives)
    second = _through_every_stage(site, plan, "v2", last_run="pilot")
    pilot = open_record(sorted((site / "runs" / CELL / "pilot").iterdir())[-1])
    assert pilot.context["release"]["mode"] == "shadow" and pilot.context["release"]["incumbent"] == first
    promoted = cli("promote", second, "--cell", CELL, "--to", "production", "--plan", str(plan), "--site", str(site))
    assert promoted.exit_code == 0, promoted.output
    status = json.loads(cli("status", "--site", str(site), "--json").stdout)["stages"]
    production = next(s for s in status if s["stage"] == "production")
    assert production["current"] == second and production["last_good"] == first

    # a fault breaks production under the plan in force: back to the first release automatically
    knocked = {"name": "knocked-fixture", "seed": 11, "acceptance_cycles": 2,
               "faults": [{"kind": "fixture_shift", "at_cycle": 0, "dx_mm": 6.0}]}
    write_plan(plan, {**STAGES, "production": {**STAGES["production"], "runs": [knocked]}})
    result = cli("run", "--cell", CELL, "--stage", "production", "--site", str(site), "--json")
    write_plan(plan, STAGES)  # the fixture put back
    assert result.exit_code == 1
    report = json.loads(result.stdout)
    assert report["verdict"] == "fail" and report["rolled_back_to"] == first
    failed = next(g for g in report["gates"] if g["metric"] == "success_rate")
    assert failed["status"] == "fail" and any(report["evidence"][0] in e for e in failed["evidence"])
    assert json.loads(cli("verify", "--site", str(site), "--json").stdout)["ok"]

    # the next production run is the first release again, and its record says why
    again = cli("run", "--cell", CELL, "--stage", "production", "--plan", str(plan), "--site", str(site), "--json")
    assert json.loads(again.stdout)["release"] == first
    latest = sorted((site / "runs" / CELL / "production").iterdir())[-1]
    switch = open_record(latest).context["release"]["switch"]
    assert switch["kind"] == "rollback" and switch["automatic"] and switch["from"] == second and switch["to"] == first

    page = tmp_path / "release.html"
    assert cli("report", second, "-o", str(page), "--site", str(site)).exit_code == 0
    html = page.read_text()
    assert "production gates failed: success_rate" in html and "<svg" in html and "pilot" in html


def test_a_rollback_by_hand_and_nothing_to_roll_back_to(tmp_path):
    site = tmp_path / "site"
    assert cli("create", "--policy", "scripted", "--profile", CELL, "--site", str(site)).exit_code == 0  # a store
    result = cli("rollback", "--cell", CELL, "--stage", "production", "--site", str(site))
    assert result.exit_code == 2 and "nothing to roll back to" in result.stderr
