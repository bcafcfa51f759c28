"""The plan in force (the site's release-plan.yaml, else the packaged plan) decides last_good, for `run` and `promote`
alike, and a verdict rests only on runs of the plan it evaluates.

Under `release run --stage production --plan weak.yaml` (one cycle, `success_rate min: 0`) a release passed and became
last_good: at the next promotion there, or at once as the first to pass the stage, and `release rollback` went to it;
`promote --plan weak.yaml` did the same. Three one-cycle runs under another plan, or with `--scenario`, were counted
in the next verdict under the plan in force and turned its fail into a pass. A pass under a stricter extra plan took
the rollback target away; a pass an older cellguard logged without its plan stopped making its release last_good,
and nothing said so; `release status` showed such passes as plain passes.
"""

from __future__ import annotations

import json
import shutil

import pytest
import yaml
from release_helpers import CELL, KNOCKED, ONE, cli, edit_store, log_pass, pointers, stored_release, write_plan

from cellguard.release import Store, load_plan, log, promote
from cellguard.release.plan import PICK_PLACE_PLAN
from cellguard.release.promotion import plan_hash, runs_key

PRODUCTION = {"runs": [ONE], "gates": [{"metric": "success_rate", "min": 1.0}]}
WEAK = {"production": {"runs": [ONE], "gates": [{"metric": "success_rate", "min": 0}]}}
STRICT = {"production": {"runs": [ONE, {**ONE, "name": "two"}], "gates": [{"metric": "success_rate", "min": 1.0}]}}


def _site(tmp_path, notes, production=PRODUCTION):
    """A site whose plan is the packaged one with ``production`` as its production stage, and a release per note,
    each with the earlier stages passed on that plan: (site, its plan file, release ids)."""
    site = tmp_path / "site"
    site.mkdir()
    stages = yaml.safe_load(PICK_PLACE_PLAN.read_text())["stages"]
    plan = write_plan(site / "release-plan.yaml", {**stages, "production": production})
    return site, plan, [stored_release(Store(site), note) for note in notes]


def _to_production(site, plan, rid, *options) -> str:
    """``rid`` through sim, bench and pilot on the site's plan (their gates logged as passed), then promoted to
    production by the CLI with ``options``: its output, on one line."""
    store, plans = Store(site), load_plan(plan)
    for stage in ("sim", "bench", "pilot"):
        promote(store, rid, CELL, stage, plans)
        log_pass(store, stage, rid)
    store.close()
    result = cli("promote", rid, "--cell", CELL, "--to", "production", *options, "--site", str(site))
    assert result.exit_code == 0, result.output
    return " ".join(result.stdout.split())


def _production(site) -> tuple:
    return next((p["current"], p["last_good"]) for p in pointers(site) if p["stage"] == "production")


def _run(site, *options, verdict: str = "pass") -> dict:
    """``release run`` at production with ``options``, ending ``verdict``: its gates entry."""
    result = cli("run", "--cell", CELL, "--stage", "production", *options, "--site", str(site))
    assert result.exit_code == (0 if verdict == "pass" else 1), result.output
    entry = next(e.body for e in reversed(log.entries(Store(site))) if e.body["kind"] == "gates")  # or a rollback's
    assert entry["verdict"] == verdict, entry
    return entry


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


def test_promote_with_a_weak_plan_takes_last_good_under_the_plan_in_force(tmp_path):
    """`promote --plan weakfull.yaml` (the site's stages, production weakened) made b's weak pass the target."""
    site, plan, (a, b, c) = _site(tmp_path, ("a", "b", "c"))
    stages = yaml.safe_load(plan.read_text())["stages"]
    weak = write_plan(tmp_path / "weakfull.yaml", {**stages, **WEAK})
    _to_production(site, plan, a)
    _run(site)
    _to_production(site, plan, b)
    _run(site, "--plan", str(weak))
    said = _to_production(site, plan, c, "--plan", str(weak))
    assert _production(site) == (c, a)
    assert f"last_good {a}, not {b}: its pass there ran another plan" in said
    entry = log.entries(Store(site))[-1].body
    assert entry["kind"] == "promote" and entry[log.IN_FORCE] == plan_hash(load_plan(plan)["production"])
    assert cli("verify", "--site", str(site)).exit_code == 0  # the replay sets the same


def test_a_pass_under_a_stricter_extra_plan_keeps_the_release_a_rollback_target(tmp_path):
    site, plan, (a, b, c) = _site(tmp_path, ("a", "b", "c"))
    _to_production(site, plan, a)
    _run(site)
    _to_production(site, plan, b)
    _run(site)
    _run(site, "--plan", str(write_plan(tmp_path / "strict.yaml", STRICT)))  # b's latest gates, another plan
    said = _to_production(site, plan, c)
    assert _production(site) == (c, b) and f"last_good {b};" in said
    assert cli("verify", "--site", str(site)).exit_code == 0


def test_promote_says_why_a_pass_logged_without_its_plan_makes_no_rollback_target(tmp_path):
    """After an upgrade, a production pass an older cellguard logged (no plan hash) left last_good where it was,
    silently."""
    site, plan, (a, b, c, d) = _site(tmp_path, ("a", "b", "c", "d"))
    _to_production(site, plan, a)
    _run(site)
    _to_production(site, plan, b)
    store = Store(site)
    with store.transaction():  # as an older cellguard logged b's pass
        older = log.append(store, {"kind": "gates", "cell": CELL, "stage": "production", "release": b,
                                   "verdict": "pass", "gates": [], "evidence": []})
    said = _to_production(site, plan, c)
    assert _production(site) == (c, a)
    assert f"last_good {a}, not {b}: its pass there logged no plan (an older cellguard; log entry {older.seq})" in said
    said = _to_production(site, plan, d)  # c never ran there
    assert f"last_good {a}, not {c}: it has no gates entry there on a plan's own runs" in said
    assert cli("verify", "--site", str(site)).exit_code == 0


def test_a_verdict_rests_only_on_runs_of_the_plan_it_evaluates(tmp_path):
    """Under a plan in force that one knocked cycle in two fails (success_rate min 0.75), the runs of an ad-hoc plan
    and of --scenario are counted by no other plan's verdict, nor its runs by theirs: runs of all of them padded
    each other's evidence."""
    in_force = {"runs": [ONE, KNOCKED], "gates": [{"metric": "success_rate", "min": 0.75}]}
    site, plan, (a,) = _site(tmp_path, ("a",), in_force)
    pad = {"production": {"runs": [{**ONE, "name": f"pad{i}"} for i in range(3)],
                          "gates": [{"metric": "success_rate", "min": 0}]}}
    _to_production(site, plan, a)
    padded = _run(site, "--plan", str(write_plan(tmp_path / "pad.yaml", pad)))
    assert len(padded["evidence"]) == 3
    alone = _run(site, verdict="fail")  # 1 of 2 cycles; with the three padding runs, 4 of 5 passed
    assert len(alone["evidence"]) == 2 and _production(site) == (a, None)
    _run(site, "--plan", str(write_plan(tmp_path / "pad.yaml", pad)))  # its own runs only: 3
    strict = _run(site, "--plan", str(write_plan(tmp_path / "strict.yaml", STRICT)))  # none of the knocked runs
    assert len(strict["evidence"]) == 2
    (tmp_path / "one.yaml").write_text(yaml.safe_dump(ONE))
    given = _run(site, "--scenario", str(tmp_path / "one.yaml"))  # the run given, alone
    assert len(given["evidence"]) == 1 and given["scenario"] == ["one"]
    edit_store(site, f"UPDATE runs SET runs_sha256 = '{runs_key(load_plan(plan)['production'])}'")  # the log decides
    again = _run(site, verdict="fail")  # its own four runs, none of the other plans' or the scenario's
    assert len(again["evidence"]) == 4 and set(alone["evidence"]) < set(again["evidence"])
    assert _production(site) == (a, None)
    assert cli("verify", "--site", str(site)).exit_code == 0


def _shown(site, rid) -> tuple[str, str]:
    """(`release status`'s production line, `release report`'s production verdict) for ``rid``, current there."""
    shown = cli("status", "--site", str(site))
    assert shown.exit_code == 0, shown.output
    page = site.parent / "page.html"
    assert cli("report", rid, "-o", str(page), "--site", str(site)).exit_code == 0
    text = page.read_text()
    head = text[text.index("<h2>production</h2>"):]
    line = " ".join(shown.stdout.split()).split(" production ")[-1].split(f" {CELL}: ")[0]  # as wrapped or not
    return line, head[:head.index("(log entry")]


def test_status_and_report_show_a_pass_that_counts_for_nothing_as_such(tmp_path):
    """`release report` showed every such pass as a plain pass."""
    site, plan, (a,) = _site(tmp_path, ("a",))
    _to_production(site, plan, a)
    _run(site, "--plan", str(write_plan(tmp_path / "weak.yaml", WEAK)))
    line, page = _shown(site, a)
    assert line.endswith("pass (other plan)") and "<b>pass</b> (other plan: counts for nothing)" in page
    _run(site)
    line, page = _shown(site, a)
    assert line.endswith(" pass") and "<div class=ok><b>pass</b> " in page
    (tmp_path / "one.yaml").write_text(yaml.safe_dump(ONE))
    _run(site, "--scenario", str(tmp_path / "one.yaml"))
    line, page = _shown(site, a)
    assert line.endswith("pass (scenario)") and "<b>pass</b> (scenario: counts for nothing)" in page


def test_status_and_report_judge_a_pass_by_the_plan_in_force_now(tmp_path):
    """They judged it by the plan in force its entry logged: a pass under a plan edited since, or one an older
    cellguard logged under another plan (no plan in force logged), showed as a plain pass that promote then refused.
    A plan in force that does not load is said, and the read-only commands still answer."""
    site, plan, (a,) = _site(tmp_path, ("a",))
    _to_production(site, plan, a)
    _run(site)
    write_plan(plan, {**yaml.safe_load(plan.read_text())["stages"],
                      "production": {**PRODUCTION, "gates": [{"metric": "success_rate", "min": 0.5}]}})
    line, page = _shown(site, a)
    assert line.endswith("pass (plan edited since)") and "(plan edited since: counts for nothing)" in page
    rows = json.loads(cli("status", "--json", "--site", str(site)).stdout)["stages"]
    assert [r["not_counted"] for r in rows if r["stage"] == "production"] == ["plan edited since"]
    store = Store(site)
    with store.transaction():  # as 80ed4fe logged a pass under --plan weak.yaml: its plan, none in force
        log.append(store, {"kind": "gates", "cell": CELL, "stage": "production", "release": a, "verdict": "pass",
                           "gates": [], "evidence": [], "plan_sha256": plan_hash(load_plan(
                               write_plan(tmp_path / "weak.yaml", WEAK))["production"])})
    line, page = _shown(site, a)
    assert line.endswith("pass (plan differs from the one in force)") and \
        "(plan differs from the one in force: counts for nothing)" in page
    plan.write_text("stages: [unclosed\n")
    line, page = _shown(site, a)
    assert line.endswith("pass (plan in force does not load)")
    said = " ".join(cli("status", "--site", str(site)).stdout.split())
    assert f"{CELL}: the plan in force does not load, so nothing is promoted or run there until it does: {plan}" in said
    whole = (site.parent / "page.html").read_text()
    assert "<p class=finding>the plan in force does not load, so no pass counts there: " in whole


def test_a_gate_added_to_the_plan_in_force_keeps_last_goods_runs_compared(tmp_path):
    """Runs were taken by the whole plan's hash: a gate added dropped all of last_good's runs, the relative gate fell
    back to its absolute limit saying 'no last_good on this stage', and the release that failed it stayed in
    production. Only runs made otherwise (the runs edited) are left out of the comparison, and it says so."""
    relative = {"runs": [ONE], "gates": [{"metric": "success_rate", "min": 0},
                                         {"metric": "cycle_time_p95_s", "max": 60.0, "max_vs_last_good": 0.5}]}
    site, plan, (a, b) = _site(tmp_path, ("a", "b"), relative)
    _to_production(site, plan, a)
    first = _run(site)
    stages = yaml.safe_load(plan.read_text())["stages"]
    added = {**relative, "gates": [*relative["gates"], {"metric": "protective_stops", "max": 0}]}
    write_plan(plan, {**stages, "production": added})
    _to_production(site, plan, b)
    failed = _run(site, verdict="fail")
    gate = next(g for g in failed["gates"] if g["metric"] == "cycle_time_p95_s")
    assert "x last_good" in gate["detail"] and failed["last_good_evidence"] == first["evidence"]
    assert _production(site) == (a, a)  # rolled back
    write_plan(plan, {**stages, "production": {**added, "runs": [{**ONE, "seed": 6}]}})  # the runs edited
    result = cli("promote", b, "--cell", CELL, "--to", "production", "--site", str(site))
    assert result.exit_code == 0, result.output
    passed = _run(site)
    gate = next(g for g in passed["gates"] if g["metric"] == "cycle_time_p95_s")
    assert gate["detail"].endswith(f"(last_good {a} has no runs of this stage's runs: absolute limit only)")
    assert passed["last_good_evidence"] == [] and cli("verify", "--site", str(site)).exit_code == 0


def test_runs_an_older_cellguard_counted_under_its_whole_plan_are_counted_under_that_plan(tmp_path):
    """A gates entry of 80ed4fe logged the whole plan's hash, not its runs': its runs stay comparable under that
    same plan (after an upgrade, last_good's runs were otherwise never compared again), and under no other."""
    site, plan, (a,) = _site(tmp_path, ("a",))
    _to_production(site, plan, a)
    first = _run(site)
    store = Store(site)
    row = store.runs(CELL, "production", a)[0]
    copy = store.site / "runs" / CELL / "production" / "0099-older"
    shutil.copytree(store.run_folder(row), copy)
    store.add_run(row.record_id, CELL, "production", a, "older", copy,
                  log.last_pointer_move(store, CELL, "production").seq, None)  # as an older cellguard counted it
    older = [store.runs(CELL, "production", a)[-1].seq, row.record_id]
    with store.transaction():  # nor has its gates entry a runs hash
        log.append(store, {"kind": "gates", "cell": CELL, "stage": "production", "release": a, "verdict": "pass",
                           "gates": [], "evidence": [row.record_id], "runs": [older],
                           "plan_sha256": plan_hash(load_plan(plan)["production"])})
    assert first["runs"][0] in _run(site)["runs"] and older in log.entries(store)[-1].body["runs"]
    other = _run(site, "--plan", str(write_plan(tmp_path / "same-runs.yaml", WEAK)))  # the same runs, other gates
    assert first["runs"][0] in other["runs"] and older not in other["runs"]
    assert cli("verify", "--site", str(site)).exit_code == 0


def test_a_store_of_an_older_cellguard_reads_its_runs_as_its_log_counted_them(tmp_path):
    """Its runs table has no plan column: a command that only reads leaves it so; the first run adds it, and the
    runs counted before are taken under the plan their gates entry logged."""
    site, plan, (a,) = _site(tmp_path, ("a",))
    _to_production(site, plan, a)
    first = _run(site)
    edit_store(site, "ALTER TABLE runs DROP COLUMN runs_sha256")  # as an older cellguard made it
    assert cli("status", "--site", str(site)).exit_code == 0
    assert "runs_sha256" not in _run_columns(site)
    again = _run(site)
    assert "runs_sha256" in _run_columns(site)
    assert len(again["evidence"]) == 2 and first["evidence"][0] in again["evidence"]


def _run_columns(site) -> list[str]:
    return [r[1] for r in Store(site).db.execute("PRAGMA table_info(runs)")]


def test_a_promotion_an_older_cellguard_logged_replays_as_it_was_decided(tmp_path):
    """Its outgoing release's latest gates of any plan decided last_good: b's pass under a stricter extra plan left
    a there. Replayed by the rule that now keeps b, `verify` called the pointers edited and every command refused."""
    site, plan, (a, b, c) = _site(tmp_path, ("a", "b", "c"))
    _to_production(site, plan, a)
    _run(site)
    _to_production(site, plan, b)
    _run(site)
    _run(site, "--plan", str(write_plan(tmp_path / "strict.yaml", STRICT)))
    store, plans = Store(site), load_plan(plan)
    for stage in ("sim", "bench", "pilot"):
        promote(store, c, CELL, stage, plans)
        log_pass(store, stage, c)
    with store.transaction():  # as the cellguard before promoted c: no outgoing_gates, a stays last_good
        store.set_pointers(CELL, "production", c, a)
        log.append(store, {"kind": "promote", "cell": CELL, "stage": "production", "release": c, "from": b, "to": c,
                           log.IN_FORCE: plan_hash(plans["production"]), "gates": [], "evidence": [],
                           "gates_entry": None})
    assert cli("verify", "--site", str(site)).exit_code == 0
    _run(site)
    assert _production(site) == (c, a)


@pytest.mark.parametrize("broken", ["folder", "dangling link"])
def test_a_site_plan_that_is_no_file_is_an_error_not_the_packaged_plan(tmp_path, broken):
    """A release-plan.yaml that is a folder or a link to nothing was passed over: the packaged plan's gates judged
    and promoted the site's releases without a word. Every command that takes the plan in force names it, exit 2,
    and nothing moves."""
    site = tmp_path / "site"
    site.mkdir()
    rid = stored_release(Store(site), "a")
    before = len(log.entries(Store(site)))
    plan = site / "release-plan.yaml"
    plan.mkdir() if broken == "folder" else plan.symlink_to(tmp_path / "moved-away.yaml")
    for args in (("promote", rid, "--cell", CELL, "--to", "sim"), ("run", "--cell", CELL, "--stage", "sim")):
        result = cli(*args, "--site", str(site))
        assert result.exit_code == 2, result.output
        assert "release-plan.yaml" in result.output and broken.split()[-1] in result.output, result.output
    assert len(log.entries(Store(site))) == before
    assert all(p["current"] is None for p in pointers(site))
