"""A pass makes its release last_good only under the stage's part of the plan in force, as it promotes only so.

Under `release run --stage production --plan weak.yaml` (one cycle, `success_rate min: 0`) a release passed and became
last_good: at the next promotion there, or at once as the first to pass the stage, and `release rollback` went to it.
"""

from __future__ import annotations

import yaml
from release_helpers import CELL, ONE, cli, log_pass, pointers, stored_release, write_plan

from cellguard.release import Store, load_plan, promote
from cellguard.release.plan import PICK_PLACE_PLAN

PRODUCTION = {"runs": [ONE], "gates": [{"metric": "success_rate", "min": 1.0}]}
WEAK = {"production": {"runs": [ONE], "gates": [{"metric": "success_rate", "min": 0}]}}


def _site(tmp_path, notes):
    """A site whose plan is the packaged one with a one-cycle production stage, and a release per note, each with
    the earlier stages passed on that plan: (site, its plan file, release ids)."""
    site = tmp_path / "site"
    site.mkdir()
    stages = yaml.safe_load(PICK_PLACE_PLAN.read_text())["stages"]
    plan = write_plan(site / "release-plan.yaml", {**stages, "production": PRODUCTION})
    return site, plan, [stored_release(Store(site), note) for note in notes]


def _to_production(site, plan, rid) -> None:
    """``rid`` through sim, bench and pilot on the site's plan (their gates logged as passed), then promoted to
    production by the CLI."""
    store, plans = Store(site), load_plan(plan)
    for stage in ("sim", "bench", "pilot"):
        promote(store, rid, CELL, stage, plans)
        log_pass(store, stage, rid)
    store.close()
    result = cli("promote", rid, "--cell", CELL, "--to", "production", "--site", str(site))
    assert result.exit_code == 0, result.output


def _production(site) -> tuple:
    return next((p["current"], p["last_good"]) for p in pointers(site) if p["stage"] == "production")


def _run(site, *plan) -> None:
    result = cli("run", "--cell", CELL, "--stage", "production", *plan, "--site", str(site))
    assert result.exit_code == 0, result.output


def test_a_pass_on_an_ad_hoc_plan_is_no_rollback_target(tmp_path):
    site, plan, (a, b, c) = _site(tmp_path, ("a", "b", "c"))
    weak = write_plan(tmp_path / "weak.yaml", WEAK)
    _to_production(site, plan, a)
    _run(site)  # the plan in force: a is its own last_good
    _to_production(site, plan, b)
    assert _production(site) == (b, a)
    ad_hoc = cli("run", "--cell", CELL, "--stage", "production", "--plan", str(weak), "--site", str(site))
    assert ad_hoc.exit_code == 0, ad_hoc.output
    _to_production(site, plan, c)
    assert _production(site) == (c, a)  # b's pass on the weak plan made it last_good
    assert "not the plan in force" in " ".join(ad_hoc.stdout.split())  # and it said so
    back = cli("rollback", "--cell", CELL, "--stage", "production", "--site", str(site))
    assert back.exit_code == 0 and _production(site) == (a, a), back.output
    write_plan(site / "release-plan.yaml", {"production": WEAK["production"]})  # an edit moves no pointer set before
    assert cli("verify", "--site", str(site)).exit_code == 0
    assert _production(site) == (a, a)


def test_the_first_pass_makes_its_release_last_good_only_on_the_plan_in_force(tmp_path):
    site, plan, (a,) = _site(tmp_path, ("a",))
    _to_production(site, plan, a)
    _run(site, "--plan", str(write_plan(tmp_path / "weak.yaml", WEAK)))
    assert _production(site) == (a, None)  # a was its own last_good, kept as such by the next promotion
    same = write_plan(tmp_path / "same.yaml", {"production": PRODUCTION})  # another file, the same stage: in force
    _run(site, "--plan", str(same))
    assert _production(site) == (a, a)
    assert cli("verify", "--site", str(site)).exit_code == 0
