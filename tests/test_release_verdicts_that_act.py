"""Only a verdict on the plan in force's own runs moves a pointer. A production fail under an ad-hoc `--plan` (one run
of one cycle against `cycle_time_p95_s max: 1.0`) or on a `--scenario` run rolled production back to last_good,
though a pass there lets nothing on. Such a fail is logged, moves nothing and the run says so in one line (exit 1); a
fail under the plan in force still rolls back."""

from __future__ import annotations

import json

import pytest
import yaml
from release_helpers import CELL, ONE, cli, log_pass, pointers, stored_release, to_production, write_plan

from cellguard.release import Store, log

SLOW = {"runs": [ONE], "gates": [{"metric": "cycle_time_p95_s", "max": 1.0}]}  # no arm cycle is that fast


def _site(tmp_path) -> tuple:
    """A site whose plan in force fails every production run, with b current in production and a its last_good:
    (site, a, b)."""
    site = tmp_path / "site"
    site.mkdir()
    write_plan(site / "release-plan.yaml", {"production": SLOW})
    store = Store(site)
    a, b = stored_release(store, "a"), stored_release(store, "b")
    to_production(store, a)
    log_pass(store, "production", a)  # a passed production: the rollback target
    to_production(store, b)
    store.close()
    return site, a, b


def _production(site) -> tuple:
    return next((p["current"], p["last_good"]) for p in pointers(site) if p["stage"] == "production")


def _run(site, *options):
    return cli("run", "--cell", CELL, "--stage", "production", *options, "--site", str(site))


@pytest.mark.parametrize("given", ["--plan", "--scenario"])
def test_a_fail_that_does_not_count_is_logged_and_rolls_nothing_back(tmp_path, given):
    site, a, b = _site(tmp_path)
    if given == "--plan":  # another plan than the one in force at production, failing as it does
        other = write_plan(tmp_path / "other.yaml", {"production": {**SLOW, "runs": [{**ONE, "seed": 6}]}})
    else:
        other = tmp_path / "one.yaml"
        other.write_text(yaml.safe_dump(ONE))
    result = _run(site, given, str(other))
    said = " ".join(result.stdout.split())
    assert result.exit_code == 1, result.output
    assert f"production on {CELL}, release {b}: fail" in said
    assert said.count("this fail is logged and rolls nothing back") == 1 and "rolled back" not in said
    assert _production(site) == (b, a)
    entries = log.entries(Store(site))
    assert entries[-1].body["kind"] == "gates" and entries[-1].body["verdict"] == "fail"  # no rollback after it

    counted = _run(site, "--json")  # the plan in force's fail still rolls back
    assert counted.exit_code == 1, counted.output
    report = json.loads(counted.stdout)
    assert report["rolled_back_to"] == a and report["acts"] and _production(site) == (a, a)
    assert cli("verify", "--site", str(site)).exit_code == 0
