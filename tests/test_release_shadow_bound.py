"""A counted pilot run's shadow rows are bound to it as its record is: the row keeps the sha256 of its
shadow.json, and a file edited, gone or damaged since is refused naming its folder. Every chunk of a passing
candidate's file marked stopped failed it; a failing candidate's file cleared let it pass. A store an older
cellguard wrote (no shadow column) still reads and verifies; its shadow rows are read as found.

The log signs each counted run's shadow hash too (a gates entry's ``log.SHADOWS``: [seq, sha256]): kept in the runs
table alone, a file edited together with its row passed `release verify` and turned the next verdict. A log an older
cellguard wrote (no shadow hashes) still verifies and reads as before."""

from __future__ import annotations

import hashlib
import json
import shutil
import sqlite3

import pytest
from release_helpers import CELL, cli, edit_store, log_pass, replay_file, write_plan

from cellguard.release import Store, create_bundle, evaluate_stage, load_plan, log, promote, run_stage
from cellguard.release.bundle import canonical_json
from cellguard.release.errors import ReleaseError
from cellguard.release.evidence import SHADOW_FILE
from cellguard.release.store import STORE_FILE

GATES = [{"metric": "success_rate", "min": 1.0}, {"metric": "shadow_would_clamp", "max": 0.05},
         {"metric": "shadow_would_stop", "max": 0}]


def _pilot_site(root, candidate: str):
    """A site where ``candidate`` ran its pilot (one shadow run of one cycle): (site, plan, that result)."""
    plan = load_plan(write_plan(root / "plan.yaml", {"pilot": {"shadow": True, "gates": GATES, "runs": [
        {"name": "shadow", "seed": 9, "acceptance_cycles": 1}]}}))["pilot"]
    store = Store(root / "site")
    bundle = create_bundle(candidate, None, CELL, None)
    store.add_bundle(bundle)
    for before, stage in ((None, "sim"), ("sim", "bench"), ("bench", "pilot")):
        if before:
            log_pass(store, before, bundle.id)
        promote(store, bundle.id, CELL, stage)
    return root / "site", plan, run_stage(store, plan, CELL, "pilot")


@pytest.fixture(scope="module")
def pilots(tmp_path_factory):
    """A candidate that passes its pilot (the taught program beside itself) and one that fails it (0.4 rad off)."""
    passing = _pilot_site(tmp_path_factory.mktemp("passing"), "scripted")
    root = tmp_path_factory.mktemp("failing")
    failing = _pilot_site(root, f"replay:{replay_file(root / 'wild.npz', offset=0.4)}")
    assert passing[2].verdict == "pass" and failing[2].verdict == "fail"
    return {"pass": passing, "fail": failing}


def _copy(pilots, which: str, tmp_path):
    """(site, plan, the pilot run's folder, its release) in a copy of the ``which`` pilot's site."""
    site, plan, result = pilots[which]
    shutil.copytree(site, tmp_path / "site")
    return tmp_path / "site", plan, tmp_path / "site" / result.folders[0][len(str(site)) + 1:], result.release


def _mark(folder, stopped: bool) -> None:
    """Every chunk of the run's shadow file made a would-be stop (or cleared of every clamp and stop)."""
    path = folder / SHADOW_FILE
    doc = json.loads(path.read_text())
    for row in doc["chunks"]:
        row.update(stopped=stopped, clamped=False, events=["protective_stop"] if stopped else [], distance_rad=0.0)
    path.write_text(json.dumps(doc))


@pytest.mark.parametrize("which, edit, why", [
    ("pass", lambda f: _mark(f, stopped=True), "hashes to"),
    ("fail", lambda f: _mark(f, stopped=False), "hashes to"),
    ("fail", lambda f: (f / SHADOW_FILE).unlink(), "is gone"),
    ("pass", lambda f: (f / SHADOW_FILE).write_text("{"), "not a shadow record"),
])
def test_a_shadow_file_changed_since_its_run_was_counted_is_refused_and_turns_no_verdict(pilots, tmp_path, which,
                                                                                          edit, why):
    site, plan, folder, _ = _copy(pilots, which, tmp_path)
    edit(folder)
    again = evaluate_stage(Store(site), plan, CELL, "pilot")
    assert again.verdict == "inconclusive" and again.evidence == ()
    assert len(again.refused) == 1 and str(folder) in again.refused[0] and why in again.refused[0]
    assert all(g.status == "inconclusive" for g in again.gates)


def test_a_store_an_older_cellguard_wrote_reads_and_verifies_and_its_shadow_rows_are_read_as_found(pilots, tmp_path):
    """Its runs have no shadow hash: read-only commands leave the table so; the run is evidence as before; the next
    run adds the column and binds its own file."""
    site, plan, folder, _ = _copy(pilots, "pass", tmp_path)
    edit_store(site, "ALTER TABLE runs DROP COLUMN shadow_sha256")  # as the cellguard before made it
    _as_older_cellguard_logged(site)  # and its log: no shadow hashes
    for command in ("status", "verify"):
        assert cli(command, "--site", str(site)).exit_code == 0
    store = Store(site)
    assert "shadow_sha256" not in [r[1] for r in store.db.execute("PRAGMA table_info(runs)")]
    older = store.runs(CELL, "pilot", pilots["pass"][2].release)[0]
    assert older.shadow is None
    assert evaluate_stage(store, plan, CELL, "pilot").evidence == (older.record_id,)
    newer = run_stage(store, plan, CELL, "pilot")
    assert newer.verdict == "pass" and len(newer.evidence) == 2 and newer.refused == ()
    row = store.runs(CELL, "pilot", newer.release)[-1]
    assert row.shadow is not None
    _mark(store.run_folder(row), stopped=True)
    assert str(store.run_folder(row)) in evaluate_stage(store, plan, CELL, "pilot").refused[0]
    assert cli("verify", "--site", str(site)).exit_code == 0


@pytest.mark.parametrize("which, stopped", [("pass", True), ("fail", False)])
def test_a_shadow_file_edited_with_its_runs_row_is_named_by_verify_and_turns_no_verdict(pilots, tmp_path, which,
                                                                                         stopped):
    site, plan, folder, release = _copy(pilots, which, tmp_path)
    counted = Store(site).runs(CELL, "pilot", release)[0]
    _mark(folder, stopped=stopped)
    edited = hashlib.sha256((folder / SHADOW_FILE).read_bytes()).hexdigest()
    edit_store(site, f"UPDATE runs SET shadow_sha256 = '{edited}' WHERE seq = {counted.seq}")
    said = cli("verify", "--site", str(site))
    assert said.exit_code == 1
    assert (f"run {counted.seq} (record {counted.record_id} of release {release}), counted by log entry "
            f"{log.size(Store(site))}, now holds shadow file hash {edited[:16]}, not {counted.shadow[:16]}"
            in " ".join(said.stdout.split()))
    if which == "pass":  # the pass logged before the edit lets it on no further
        with pytest.raises(ReleaseError, match="now holds shadow file hash"):
            promote(Store(site), release, CELL, "production")
    again = evaluate_stage(Store(site), plan, CELL, "pilot")
    assert again.verdict == "inconclusive" and again.evidence == ()
    assert len(again.refused) == 1 and str(folder) in again.refused[0]
    assert f"hashes to {edited[:16]}, not {counted.shadow[:16]}" in again.refused[0]
    assert log.entries(Store(site))[-1].body[log.SHADOWS] == [[counted.seq, counted.shadow]]  # what was counted


def _as_older_cellguard_logged(site) -> None:
    """The log rewritten as the cellguard before logged it: no shadow hashes, the chain and the store's head hashed
    again over those bodies."""
    db = sqlite3.connect(site / STORE_FILE)
    prev = log.GENESIS
    for seq, text in db.execute("SELECT seq, body FROM log ORDER BY seq").fetchall():
        body = json.loads(text)
        body.pop(log.SHADOWS, None)
        digest = log.entry_hash(prev, body)
        db.execute("UPDATE log SET body = ?, prev_hash = ?, hash = ? WHERE seq = ?",
                   (canonical_json(body).decode(), prev, digest, seq))
        prev = digest
    db.execute("UPDATE meta SET value = ? WHERE key = 'log_head'", (prev,))
    db.commit()
    db.close()


def test_a_log_an_older_cellguard_wrote_without_shadow_hashes_verifies_and_reads_as_before(pilots, tmp_path):
    site, plan, folder, release = _copy(pilots, "pass", tmp_path)
    _as_older_cellguard_logged(site)
    store = Store(site)
    counted = store.runs(CELL, "pilot", release)[0]
    assert log.SHADOWS not in log.entries(store)[-1].body
    assert cli("verify", "--site", str(site)).exit_code == 0
    again = evaluate_stage(store, plan, CELL, "pilot")
    assert again.verdict == "pass" and again.evidence == (counted.record_id,) and again.refused == ()
    promote(store, release, CELL, "production")
    assert cli("verify", "--site", str(site)).exit_code == 0
    _mark(folder, stopped=True)  # its row still binds the file
    assert "hashes to" in evaluate_stage(Store(site), plan, CELL, "pilot").refused[0]
