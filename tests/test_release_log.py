"""The promotion log: an edited entry and a deleted one (middle or last) are both detected; a deleted last entry
whose head was moved back with it only against a head kept elsewhere."""

from __future__ import annotations

import json
import sqlite3

from release_helpers import CELL, cli

from cellguard.release import Store, create_bundle, promote, verify_log
from cellguard.release.log import head
from cellguard.release.store import STORE_FILE


def _site_with_entries(tmp_path, n: int = 3):
    site = tmp_path / "site"
    store = Store(site)
    for i in range(n):
        bundle = create_bundle("scripted", None, CELL, None, note=f"v{i}")
        store.add_bundle(bundle)
        promote(store, bundle.id, CELL, "sim")
    store.close()
    return site


def test_a_whole_log_verifies(tmp_path):
    site = _site_with_entries(tmp_path)
    result = cli("verify", "--site", str(site), "--json")
    assert result.exit_code == 0
    doc = json.loads(result.stdout)
    assert {k: doc[k] for k in ("entries", "head", "ok", "log_ok", "problems")} == {
        "entries": 3, "head": head(Store(site)), "ok": True, "log_ok": True, "problems": []}
    assert doc["inputs"]["changed"] == []  # the live releases' files too (test_release_verify_files.py)


def test_an_edited_entry_is_detected(tmp_path):
    site = _site_with_entries(tmp_path)
    db = sqlite3.connect(site / STORE_FILE)
    body = json.loads(db.execute("SELECT body FROM log WHERE seq=2").fetchone()[0])
    body["from"] = "someone-else"
    db.execute("UPDATE log SET body=? WHERE seq=2", (json.dumps(body),))
    db.commit()
    result = cli("verify", "--site", str(site))
    assert result.exit_code == 1 and "entry 2: content does not match its hash (edited)" in result.stdout
    assert "log whole" not in result.stdout and "calibration): whole;" in result.stdout  # the files' own result
    doc = json.loads(cli("verify", "--site", str(site), "--json").stdout)
    assert not doc["log_ok"] and not doc["ok"] and doc["inputs"]["changed"] == []


def test_a_deleted_entry_is_detected_in_the_middle_and_at_the_end(tmp_path):
    site = _site_with_entries(tmp_path)
    db = sqlite3.connect(site / STORE_FILE)
    db.execute("DELETE FROM log WHERE seq=2")
    db.commit()
    problems = verify_log(Store(site))
    assert any("entries 2..2 missing" in p for p in problems)
    assert any(p.startswith("entry 3: previous hash") for p in problems)
    site2 = _site_with_entries(tmp_path / "b")
    db = sqlite3.connect(site2 / STORE_FILE)
    db.execute("DELETE FROM log WHERE seq=3")
    db.commit()
    result = cli("verify", "--site", str(site2))
    assert result.exit_code == 1 and "the last entries were deleted" in result.stdout


def test_a_last_entry_deleted_with_the_head_moved_back_is_found_only_against_a_head_kept_elsewhere(tmp_path):
    """Nothing in the same file tells such a log from one that was never longer: ``--expect-head`` does."""
    site = _site_with_entries(tmp_path)
    kept = json.loads(cli("verify", "--site", str(site), "--json").stdout)["head"]
    db = sqlite3.connect(site / STORE_FILE)
    prev = db.execute("SELECT prev_hash FROM log WHERE seq=3").fetchone()[0]
    db.execute("DELETE FROM log WHERE seq=3")
    db.execute("UPDATE meta SET value=? WHERE key='log_head'", (prev,))
    db.execute("UPDATE meta SET value='2' WHERE key='log_count'")
    db.execute("UPDATE pointers SET current=(SELECT json_extract(body, '$.to') FROM log WHERE seq=2)")  # as before
    db.commit()
    assert cli("verify", "--site", str(site)).exit_code == 0
    result = cli("verify", "--site", str(site), "--expect-head", kept[:16])
    assert result.exit_code == 1 and f"no entry has the expected head {kept[:16]}" in result.stdout
    assert cli("verify", "--site", str(site), "--expect-head", prev).exit_code == 0  # an older head: still held
    bad = cli("verify", "--site", str(site), "--expect-head", "xyz")
    assert bad.exit_code == 2 and bad.stderr.count("\n") == 1 and "not a hash" in bad.stderr


def test_an_entry_edited_between_two_reads_of_one_store_is_refused_at_the_second(tmp_path):
    """A store keeps each row it checked (``log.entries``): one edited meanwhile from another connection, even
    re-hashed over its stored text, is checked again and refused; put back, it reads again."""
    import hashlib

    import pytest

    from cellguard.release import log
    from cellguard.release.errors import ReleaseError

    store = Store(_site_with_entries(tmp_path))
    assert len(log.entries(store)) == 3
    db = sqlite3.connect(store.site / STORE_FILE)
    text, prev = db.execute("SELECT body, prev_hash FROM log WHERE seq=2").fetchone()
    forged = text.replace('"to":', '"to":"elsewhere","to":', 1)  # a duplicate key, its text hashed as stored
    assert forged != text
    db.execute("UPDATE log SET body=?, hash=? WHERE seq=2",
               (forged, hashlib.sha256(prev.encode() + forged.encode()).hexdigest()))
    db.commit()
    with pytest.raises(ReleaseError, match="log entry 2: content does not match its hash"):
        log.entries(store)
    assert any(p.startswith("entry 2: content does not match its hash") for p in verify_log(store))
