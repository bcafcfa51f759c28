"""The release store against races and hand edits: racing promotions, a broken log body, edited pointers,
a site with no store, a report's output path, release id prefixes taken literally."""

from __future__ import annotations

import sqlite3
import threading

import pytest
from release_helpers import CELL, cli, edit_store, log_pass, promoted_site

from cellguard.release import Store, create_bundle, promote, verify_log
from cellguard.release.errors import StageError
from cellguard.release.log import entries
from cellguard.release.store import STORE_FILE


def test_two_promotions_racing_for_the_store_move_the_stage_once(tmp_path):
    site = tmp_path / "site"
    store = Store(site)
    bundle = create_bundle("scripted", None, CELL, None)
    store.add_bundle(bundle)
    store.close()
    both_read = threading.Barrier(2, timeout=60)  # both have read the pointers before either takes the write lock
    outcomes = []

    def racer():
        mine = Store(site)
        mine.db.set_trace_callback(lambda sql: sql == "BEGIN IMMEDIATE" and both_read.wait())
        try:
            outcomes.append(promote(mine, bundle.id, CELL, "sim").body["from"])
        except StageError as exc:
            outcomes.append(str(exc))
        finally:
            mine.close()

    threads = [threading.Thread(target=racer) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    moves = [e.body for e in entries(Store(site)) if e.body["kind"] == "promote"]
    assert len(moves) == 1 and moves[0]["from"] is None
    assert None in outcomes and any(isinstance(o, str) and "already current" in o for o in outcomes)
    assert verify_log(Store(site)) == []


@pytest.mark.parametrize("body", ["not json", "[1]"])
def test_a_log_entry_that_is_not_a_json_object_is_named_not_a_traceback(tmp_path, body):
    site, _ = promoted_site(tmp_path, ("v1", "v2"))
    edit_store(site, f"UPDATE log SET body='{body}' WHERE seq=1")
    verify = cli("verify", "--site", str(site))
    assert verify.exit_code == 1 and "broken: entry 1: not a JSON object (edited)" in verify.stdout
    status = cli("status", "--site", str(site))
    assert status.exit_code == 2 and status.stdout == ""
    assert status.stderr.startswith("error: ") and status.stderr.count("\n") == 1 and "log entry 1" in status.stderr


@pytest.mark.parametrize("command", [("verify",), ("status",), ("report", "abcd", "-o", "page.html")])
def test_a_read_only_command_on_a_site_with_no_store_refuses_and_creates_nothing(tmp_path, command):
    typo = tmp_path / "typo"
    result = cli(*command, "--site", str(typo))
    assert result.exit_code == 2 and result.stderr.count("\n") == 1 and "no release store" in result.stderr
    assert not typo.exists()


@pytest.mark.parametrize("edit", ["current='0000000000000000', last_good='0000000000000000'",
                                  "last_good=current"])
def test_edited_pointers_are_found_by_verify(tmp_path, edit):
    site, (_, second) = promoted_site(tmp_path, ("v1", "v2"))
    assert cli("verify", "--site", str(site)).exit_code == 0
    edit_store(site, f"UPDATE pointers SET {edit} WHERE stage='sim'")
    result = cli("verify", "--site", str(site))
    assert result.exit_code == 1 and "broken: pointers of sim on arm-pick-place" in result.stdout
    assert f"the log says current {second}, last_good None" in result.stdout


def test_a_deleted_pointer_row_is_found_by_verify(tmp_path):
    site, _ = promoted_site(tmp_path)
    edit_store(site, "DELETE FROM pointers")
    result = cli("verify", "--site", str(site))
    assert result.exit_code == 1 and "broken: pointers of sim on arm-pick-place: current None" in result.stdout


def test_a_report_into_a_folder_is_refused_and_a_file_named_like_a_temporary_is_kept(tmp_path):
    site, (rid,) = promoted_site(tmp_path)
    folder = tmp_path / "pages"
    folder.mkdir()
    result = cli("report", rid, "-o", str(folder), "--site", str(site))
    assert result.exit_code == 2 and result.stderr.count("\n") == 1 and "is a folder" in result.stderr
    assert set(tmp_path.iterdir()) == {site, folder}  # no temporary left beside it
    assert list(folder.iterdir()) == []
    page, mine = tmp_path / "release.html", tmp_path / "release.html.tmp"
    mine.write_text("the operator's own file")
    assert cli("report", rid, "-o", str(page), "--site", str(site)).exit_code == 0
    assert mine.read_text() == "the operator's own file" and "<h1>cellguard release" in page.read_text()
    assert set(tmp_path.iterdir()) == {site, folder, page, mine}


@pytest.mark.parametrize("prefix", [lambda rid: "_" + rid[1:4], lambda rid: rid[:3] + "%", lambda rid: "%",
                                    lambda rid: "", lambda rid: rid[:4] + " "])
def test_a_release_prefix_is_hex_and_taken_literally(tmp_path, prefix):
    site, (rid,) = promoted_site(tmp_path)
    result = cli("promote", prefix(rid), "--cell", CELL, "--to", "sim", "--site", str(site))
    assert result.exit_code == 2 and result.stderr.count("\n") == 1 and "not a release id" in result.stderr


def test_a_promotion_from_hand_edited_pointers_is_refused_and_moves_nothing(tmp_path):
    """The log, not an edited pointers row, says where a stage is: a move from elsewhere is not logged."""
    site, (first, second) = promoted_site(tmp_path, ("v1", "v2"))
    edit_store(site, f"UPDATE pointers SET current='{first}', last_good='{second}' WHERE stage='sim'")  # log: second
    before = len(entries(Store(site)))
    result = cli("rollback", "--cell", CELL, "--stage", "sim", "--site", str(site))
    assert result.exit_code == 2 and f"the log says current {second}" in result.stderr
    assert "nothing moved" in result.stderr and len(entries(Store(site))) == before


def test_a_report_over_the_store_or_any_store_is_refused_and_the_store_kept(tmp_path):
    """`report -o SITE/release.sqlite` replaced the release store (every bundle and the log) with the page."""
    site, (rid,) = promoted_site(tmp_path)
    store_file = site / STORE_FILE
    before = store_file.read_bytes()
    other = tmp_path / "fleet.sqlite"
    sqlite3.connect(other).execute("CREATE TABLE t (x)").connection.close()
    for target in (store_file, other):
        result = cli("report", rid, "-o", str(target), "--site", str(site))
        assert result.exit_code == 2 and result.stderr.count("\n") == 1 and str(target) in result.stderr
    assert "is the release store being read" in cli("report", rid, "-o", str(store_file), "--site", str(site)).stderr
    assert store_file.read_bytes() == before and other.read_bytes().startswith(b"SQLite format 3\x00")
    assert cli("verify", "--site", str(site)).exit_code == 0


def _gates_entry(site) -> None:
    """A gates entry for the site's release at sim, as `release run` logs one."""
    store = Store(site)
    log_pass(store, "sim", store.pointers(CELL, "sim").current)
    store.close()


EDITS = {  # a hand edit, and the commands that read what it broke
    "UPDATE log SET body=json_remove(body, '$.verdict') WHERE seq=2": ("promote", "status", "report", "run"),
    "UPDATE meta SET value='abc' WHERE key='log_count'": ("promote", "run"),  # append after it
    "UPDATE bundles SET manifest='not json'": ("promote", "report", "run"),
}


@pytest.mark.parametrize("edit", EDITS)
def test_a_hand_edited_store_is_one_line_exit_2_not_a_traceback(tmp_path, edit):
    """A gates entry without its verdict was a KeyError, a log count that is no number a ValueError, a manifest
    that is not JSON a JSONDecodeError; a run is refused before it runs (its gates could not be logged)."""
    site, (rid,) = promoted_site(tmp_path)
    _gates_entry(site)
    edit_store(site, edit)
    before = (site / STORE_FILE).read_bytes()
    commands = {"promote": ("promote", rid, "--cell", CELL, "--to", "bench"), "status": ("status",),
                "report": ("report", rid, "-o", str(tmp_path / "page.html")), "run": ("run", "--cell", CELL, "--stage",
                                                                                      "sim")}
    for name in EDITS[edit]:
        result = cli(*commands[name], "--site", str(site))
        assert result.exit_code == 2 and result.stderr.count("\n") == 1, (name, result.output)
        assert result.stderr.startswith("error: ") and "edited outside cellguard" in result.stderr
    assert (site / STORE_FILE).read_bytes() == before and not (site / "runs").exists()
    assert cli("verify", "--site", str(site)).exit_code == 1


def test_verify_finds_a_manifest_that_no_longer_hashes_to_its_id(tmp_path):
    site, (rid,) = promoted_site(tmp_path)
    edit_store(site, "UPDATE bundles SET manifest=json_set(manifest, '$.note', 'v2')")
    result = cli("verify", "--site", str(site))
    assert result.exit_code == 1 and f"broken: release {rid}: its manifest hashes to" in result.stdout
