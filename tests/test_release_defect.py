"""A subtle defect fails the sim gate with its evidence named: a clone taught with the fixture 2 mm off."""

from __future__ import annotations

import json

import pytest
from release_helpers import CELL, cli, write_plan

from cellguard.train.demo_policy import train_demo_policy

pytestmark = pytest.mark.slow


def test_a_clone_taught_on_a_mis_set_fixture_fails_the_testnet(tmp_path):
    policy = train_demo_policy(tmp_path / "off.onnx", cycles=4, seed=1, fixture_dx_mm=2.0).path
    plan = write_plan(tmp_path / "plan.yaml", {"sim": {
        "runs": [{"name": "nominal", "seed": 5, "acceptance_cycles": 1},
                 {"name": "fixture-minus-1.5mm", "seed": 6, "acceptance_cycles": 1,
                  "faults": [{"kind": "fixture_shift", "at_cycle": 0, "dx_mm": -1.5}]}],
        "gates": [{"metric": "success_rate", "min": 1.0, "min_cycles": 2},
                  {"metric": "protective_stops", "max": 0}]}})
    site = tmp_path / "site"
    rid = json.loads(cli("create", "--policy", f"onnx:{policy}", "--profile", CELL, "--site", str(site),
                         "--json").stdout)["id"]
    assert cli("promote", rid, "--cell", CELL, "--to", "sim", "--site", str(site)).exit_code == 0
    result = cli("run", "--cell", CELL, "--stage", "sim", "--plan", str(plan), "--site", str(site), "--json")
    assert result.exit_code == 1
    report = json.loads(result.stdout)
    gate = next(g for g in report["gates"] if g["metric"] == "success_rate")
    assert report["verdict"] == "fail" and gate["status"] == "fail"
    assert any("(fixture-minus-1.5mm) cycle 0: failed" in e for e in gate["evidence"])
    refused = cli("promote", rid, "--cell", CELL, "--to", "bench", "--site", str(site))
    assert refused.exit_code == 2 and "success_rate" in refused.stderr
