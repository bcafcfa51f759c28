"""Advice: a fault seen before at this site names the recovery that fixed it, with its counts.

One simulated run (intermittent slip, retry_grasp) and the same scenario run again beside it, a second run of
the same site: diagnosing the first writes what fixed each cause; the second is advised from it.
"""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.runtime import run_scenario
from cellguard.scenario import parse_scenario

runner = CliRunner()
# fault seed 27 at rate 0.4: no slip in the 5 acceptance cycles, slips in production cycles 5, 8 and 9
SCENARIO = {"cell": "arm-pick-place", "seed": 4, "acceptance_cycles": 5, "production_cycles": 6,
            "faults": [{"kind": "intermittent_slip", "rate": 0.4, "dx_mm": -5.0, "seed": 27}],
            "recovery": {"behaviours": [{"do": "retry_grasp", "trigger": "grasp_missed", "attempts": 2}]}}


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    root = tmp_path_factory.mktemp("site")
    summary = run_scenario(parse_scenario(SCENARIO), root / "run-1")
    run_scenario(parse_scenario(SCENARIO), root / "run-2")  # a copy of run-1's record is the same incident, not a second
    return root, summary


def _diagnose(folder) -> dict:
    result = runner.invoke(app, ["diagnose", str(folder), "--json"])
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout)


def test_every_recovery_is_in_the_diagnosis_with_its_outcome(site):
    root, summary = site
    d = _diagnose(root / "run-1")
    logged = [(c["cycle"], r["behaviour"], r["outcome"]) for c in summary["cycles"] for r in c.get("recovery_log", [])]
    assert logged and [(r["cycle"], r["behaviour"], r["outcome"]) for r in d["recoveries"]] == logged
    assert {c for c, _, o in logged if o == "resumed"} == {5, 8, 9}
    slip = next(f for f in d["findings"] if f["cause"] == "tool_slip")
    assert "what got the cell running again: retry_grasp (3 of 3 cycles)" in slip["evidence"]
    assert not d["advice"]  # nothing seen before at this site
    fixes = json.loads((root / "run-1" / "fixes.json").read_text())
    assert {"cause": "tool_slip", "recovery": "retry_grasp", "tried": 3, "fixed": 3}.items() <= fixes["fixes"][0].items()


def test_a_fault_seen_before_is_advised_with_the_recovery_that_fixed_it(site):
    root, _ = site
    _diagnose(root / "run-1")
    (root / "elsewhere").mkdir(exist_ok=True)
    (root / "elsewhere" / "fixes.json").write_text(json.dumps({"site": "another-site", "fixes": [
        {"cause": "tool_slip", "cycle": 1, "recovery": "rehome", "tried": 9, "fixed": 9}]}))
    (root / "broken").mkdir(exist_ok=True)
    (root / "broken" / "fixes.json").write_text("{not json")
    d = _diagnose(root / "run-2")
    advice = next(a for a in d["advice"] if a["cause"] == "tool_slip")
    assert advice["recoveries"] == [{"recovery": "retry_grasp", "fixed": 3, "tried": 3, "records": 1, "scope": "site",
                                     "success_rate": 1.0}]
    slip = next(f for f in d["findings"] if f["cause"] == "tool_slip")
    assert "seen before at this site: retry_grasp fixed it in 3 of 3 cycles (1 record(s))" in slip["evidence"]
    text = " ".join(runner.invoke(app, ["diagnose", str(root / "run-2")]).output.split())  # rich wraps at 80
    assert "seen before at this site: retry_grasp" in text
    assert "recoveries: 6 attempt(s) in 3 cycle(s): retry_grasp failed 3, retry_grasp resumed 3" in text
    assert runner.invoke(app, ["report", str(root / "run-2")]).exit_code == 0
    assert "seen before at this site: retry_grasp fixed it in 3 of 3 cycles" in (root / "run-2" / "report.html").read_text()
