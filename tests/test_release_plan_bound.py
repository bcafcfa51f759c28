"""A stage's pass lets its release on only under the plan it ran: the plan's runs and gates define the stage.

A release passed sim on any other plan (`release run --plan weak.yaml`: one run of one cycle, a gate any run
passes) and was promoted to bench under the site's plan, whose sim stage never ran."""

from __future__ import annotations

import pytest
from release_helpers import CELL, ONE, cli, promoted_site, write_plan

from cellguard.release import Store, load_plan, log, promote
from cellguard.release.errors import StageError
from cellguard.release.plan import PICK_PLACE_PLAN
from cellguard.release.promotion import plan_hash

WEAK = {"sim": {"runs": [ONE], "gates": [{"metric": "success_rate", "min": 0}]}}
STAGE = {"runs": [ONE], "gates": [{"metric": "success_rate", "min": 1.0}, {"metric": "protective_stops", "max": 0}]}


def _sim_hash(plan) -> str:
    return plan_hash(load_plan(plan)["sim"])[:12]


def test_a_pass_on_another_plan_promotes_nothing_and_the_plans_own_pass_does(tmp_path):
    site = tmp_path / "site"
    weak = write_plan(tmp_path / "weak.yaml", WEAK)
    mine = write_plan(tmp_path / "mine.yaml", {"sim": STAGE, "bench": STAGE})
    rid = cli("create", "--policy", "scripted", "--profile", CELL, "--site", str(site)).stdout.split()[1]
    assert cli("promote", rid, "--cell", CELL, "--to", "sim", "--plan", str(mine), "--site", str(site)).exit_code == 0
    assert cli("run", "--cell", CELL, "--stage", "sim", "--plan", str(weak), "--site", str(site)).exit_code == 0
    for plan in (mine, PICK_PLACE_PLAN):  # the site's plan, and the packaged one (the default)
        refused = cli("promote", rid, "--cell", CELL, "--to", "bench", "--plan", str(plan), "--site", str(site))
        assert refused.exit_code == 2 and refused.stderr.count("\n") == 1, refused.output
        assert f"passed on plan {_sim_hash(weak)} for sim (log entry 2)" in refused.stderr
        assert f"the plan in force has {_sim_hash(plan)} there" in refused.stderr
    assert Store(site).pointers(CELL, "bench").current is None
    assert cli("verify", "--site", str(site)).exit_code == 0

    assert cli("run", "--cell", CELL, "--stage", "sim", "--plan", str(mine), "--site", str(site)).exit_code == 0
    tighter_sim = write_plan(tmp_path / "tighter.yaml", {"sim": {**STAGE, "gates": STAGE["gates"][:1]}, "bench": STAGE})
    refused = cli("promote", rid, "--cell", CELL, "--to", "bench", "--plan", str(tighter_sim), "--site", str(site))
    assert refused.exit_code == 2 and _sim_hash(mine) in refused.stderr  # its sim stage edited: run it again
    later_edit = write_plan(tmp_path / "later.yaml", {"sim": STAGE, "bench": {**STAGE, "gates": STAGE["gates"][:1]}})
    promoted = cli("promote", rid, "--cell", CELL, "--to", "bench", "--plan", str(later_edit), "--site", str(site))
    assert promoted.exit_code == 0, promoted.output  # a later stage's edit changes nothing sim's runs showed


def test_a_pass_logged_without_its_plan_promotes_nothing_under_a_plan(tmp_path):
    """A gates entry of an older cellguard (no plan_sha256) cannot show which plan its runs were."""
    site, (rid,) = promoted_site(tmp_path)
    store = Store(site)
    with store.transaction():
        log.append(store, {"kind": "gates", "cell": CELL, "stage": "sim", "release": rid, "verdict": "pass",
                           "gates": [], "evidence": []})
        store.set_pointers(CELL, "sim", rid, rid)
    with pytest.raises(StageError, match="passed on a plan it did not log"):
        promote(store, rid, CELL, "bench", load_plan(PICK_PLACE_PLAN))
    assert store.pointers(CELL, "bench").current is None
