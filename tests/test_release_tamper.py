"""A store edited by hand is refused before anything runs or moves: a pointer the log did not set, an entry
deleted from the middle of the log, a counted run's row deleted or relabelled; and a pass on runs given with
`--scenario` in place of the plan's lets nothing on."""

from __future__ import annotations

import sqlite3

from release_helpers import CELL, cli, log_pass, replay_file, write_plan

from cellguard.release import Store, create_bundle, load_plan, log, promote, run_stage
from cellguard.release.store import STORE_FILE

ONE = {"name": "one", "seed": 5, "acceptance_cycles": 1}
KNOCKED = {"name": "knocked", "seed": 6, "acceptance_cycles": 1,
           "faults": [{"kind": "fixture_shift", "at_cycle": 0, "dx_mm": 10.0}]}
GATES = [{"metric": "success_rate", "min": 1.0}]


def _site(tmp_path, notes=("v1",), policy="scripted"):
    """A site and a plan of one run per stage; each release (one per note) created, the first promoted to sim."""
    plan = write_plan(tmp_path / "plan.yaml", {"sim": {"runs": [ONE], "gates": GATES},
                                               "bench": {"runs": [ONE], "gates": GATES},
                                               "pilot": {"shadow": True, "runs": [ONE], "gates": GATES},
                                               "production": {"runs": [ONE], "gates": GATES}})
    site = tmp_path / "site"
    store = Store(site)
    ids = []
    for note in notes:
        bundle = create_bundle(policy, None, CELL, None, note=note)
        store.add_bundle(bundle)
        ids.append(bundle.id)
    promote(store, ids[0], CELL, "sim")
    return plan, site, ids


def _edit(site, sql: str) -> None:
    db = sqlite3.connect(site / STORE_FILE)
    db.execute(sql)
    db.commit()
    db.close()


def _refused(result, *words):
    assert result.exit_code == 2 and result.stderr.startswith("error: ") and result.stderr.count("\n") == 1, \
        result.output
    for w in words:
        assert w in result.stderr, result.stderr


def test_a_hand_edited_pointer_is_refused_before_the_run(tmp_path):
    """`UPDATE pointers SET current=<ungated release>` ran that release in the stage and passed it."""
    plan, site, (_, ungated) = _site(tmp_path, ("v1", "v2"))
    _edit(site, f"UPDATE pointers SET current='{ungated}' WHERE stage='sim'")
    result = cli("run", "--cell", CELL, "--stage", "sim", "--plan", str(plan), "--site", str(site))
    _refused(result, f"current {ungated}", "edited outside cellguard", "nothing run")
    assert not (site / "runs").exists()


def test_an_entry_deleted_from_the_middle_of_the_log_stops_every_command(tmp_path):
    """Each entry still matched its own hash: promote and rollback went on over the gap."""
    plan, site, (first, second, third) = _site(tmp_path, ("v1", "v2", "v3"))
    store = Store(site)
    promote(store, second, CELL, "sim")
    promote(store, third, CELL, "sim")
    _edit(site, "DELETE FROM log WHERE seq=2")
    before = (site / STORE_FILE).read_bytes()
    for args in (("promote", first, "--cell", CELL, "--to", "sim"), ("rollback", "--cell", CELL, "--stage", "sim"),
                 ("run", "--cell", CELL, "--stage", "sim", "--plan", str(plan)), ("status",)):
        _refused(cli(*args, "--site", str(site)), "log entry 3: does not follow entry 1", "edited outside cellguard")
    assert (site / STORE_FILE).read_bytes() == before and not (site / "runs").exists()


def test_the_incumbent_in_shadow_is_checked_against_its_release(tmp_path):
    """Replacing the incumbent's policy file after create drove the cell with it in the pilot, and passed."""
    incumbent_file = replay_file(tmp_path / "incumbent.npz")
    _, site, (incumbent,) = _site(tmp_path, policy=f"replay:{incumbent_file}")
    plan = write_plan(tmp_path / "pilot.yaml", {"pilot": {"shadow": True, "runs": [ONE],
                                                          "gates": [{"metric": "success_rate", "min": 0}]}})
    store = Store(site)
    candidate = create_bundle("scripted", None, CELL, None, note="candidate")
    store.add_bundle(candidate)
    promote(store, candidate.id, CELL, "sim")
    for release, stages in ((incumbent, ("bench", "pilot", "production")), (candidate.id, ("bench", "pilot"))):
        for before, stage in zip(("sim", "bench", "pilot"), stages, strict=False):
            log_pass(store, before, release)
            promote(store, release, CELL, stage)
    assert run_stage(store, load_plan(plan)["pilot"], CELL, "pilot").verdict == "pass"  # the incumbent as created
    replay_file(incumbent_file, offset=0.3)  # the file under the incumbent's release, replaced
    result = cli("run", "--cell", CELL, "--stage", "pilot", "--plan", str(plan), "--site", str(site))
    _refused(result, f"release {incumbent}: policy", "changed since create")
    assert len(list((site / "runs" / CELL / "pilot").iterdir())) == 1  # the run before the swap alone


def test_a_pass_on_runs_given_with_scenario_promotes_nothing(tmp_path):
    """`--scenario` replaced the plan's runs (its fault runs), the stage passed and promotion went on."""
    plan, site, (rid,) = _site(tmp_path)
    scenario = tmp_path / "nominal.yaml"
    scenario.write_text("{name: mine, seed: 5, acceptance_cycles: 1}\n")
    ran = cli("run", "--cell", CELL, "--stage", "sim", "--plan", str(plan), "--scenario", str(scenario),
              "--site", str(site))
    assert ran.exit_code == 0 and "ran in place of the plan's runs" in " ".join(ran.stdout.split())  # wrapped
    entry = log.entries(Store(site))[-1].body
    assert entry["scenario"] == ["mine"] and len(entry["plan_sha256"]) == 64
    assert Store(site).pointers(CELL, "sim").last_good is None  # logged, not acted on: no last_good from it
    to_bench = ("promote", rid, "--cell", CELL, "--to", "bench", "--plan", str(plan), "--site", str(site))
    _refused(cli(*to_bench), "--scenario", "plan's runs")
    assert cli("run", "--cell", CELL, "--stage", "sim", "--plan", str(plan), "--site", str(site)).exit_code == 0
    assert cli(*to_bench).exit_code == 0
    assert cli("verify", "--site", str(site)).exit_code == 0


def test_a_deleted_failing_run_never_lets_a_later_evaluation_pass(tmp_path):
    """Deleting the failing run's row let the next run pass and the release be promoted."""
    plan, site, (rid,) = _site(tmp_path)
    store = Store(site)
    assert run_stage(store, load_plan(plan)["sim"], CELL, "sim", runs=[KNOCKED]).verdict == "fail"
    _edit(site, "DELETE FROM runs WHERE name='knocked'")
    again = run_stage(store, load_plan(plan)["sim"], CELL, "sim")
    assert again.verdict == "inconclusive" and "run 1 (record" in again.refused[0] and "no longer" in again.refused[0]
    verify = cli("verify", "--site", str(site))
    assert verify.exit_code == 1 and "run 1 (record" in verify.stdout and "is gone" in verify.stdout


def test_a_relabelled_run_row_is_found_by_verify_and_promote(tmp_path):
    plan, site, (rid, other) = _site(tmp_path, ("v1", "v2"))
    assert run_stage(Store(site), load_plan(plan)["sim"], CELL, "sim").verdict == "pass"
    _edit(site, f"UPDATE runs SET release='{other}'")
    verify = cli("verify", "--site", str(site))
    assert verify.exit_code == 1 and "now holds record" in verify.stdout and f"of release {other}" in verify.stdout
    _refused(cli("promote", rid, "--cell", CELL, "--to", "bench", "--plan", str(plan), "--site", str(site)),
             "counted by log entry 2")
