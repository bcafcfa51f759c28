"""A store that cannot be written (a full disk, a read-only store): every command that writes it ends in one line
naming the store and exit 2, never a traceback, and the store is left as it was (its log still verifies).

Real sqlite conditions, no root: a file-size limit (RLIMIT_FSIZE, as a full disk or a quota) so the journal takes no
page, and a header whose write version only a newer sqlite writes, so sqlite opens the store read-only (as on a
read-only mount)."""

from __future__ import annotations

import resource
from contextlib import contextmanager

import pytest
from release_helpers import CELL, cli, log_pass

from cellguard.release import Store, create_bundle, promote, verify_log
from cellguard.release.errors import ReleaseError
from cellguard.release.log import entries
from cellguard.release.store import STORE_FILE

WRITE_VERSION = 18  # the header byte sqlite reads as the file format it may write: above 2, it only reads


@contextmanager
def full(site):
    """No file may grow past 1 KiB: the store's journal cannot take the first page a write changes."""
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    resource.setrlimit(resource.RLIMIT_FSIZE, (1024, hard))
    try:
        yield "disk I/O error"
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))


@contextmanager
def read_only(site):
    """The store's header says a newer sqlite format wrote it: sqlite reads it and refuses every write."""
    with open(site / STORE_FILE, "r+b") as f:
        f.seek(WRITE_VERSION)
        was = f.read(1)
        f.seek(WRITE_VERSION)
        f.write(b"\x03")
    try:
        yield "attempt to write a readonly database"
    finally:
        with open(site / STORE_FILE, "r+b") as f:
            f.seek(WRITE_VERSION)
            f.write(was)


def _site(tmp_path, passed=()):
    """A site with releases v1 and v2 of the arm cell, those in ``passed`` promoted to sim in turn, each passing its
    gates there: (site, {note: release id})."""
    site = tmp_path / "site"
    store = Store(site)
    ids = {}
    for note in ("v1", "v2"):
        bundle = create_bundle("scripted", None, CELL, None, note=note)
        store.add_bundle(bundle)
        ids[note] = bundle.id
        if note in passed:
            promote(store, bundle.id, CELL, "sim")
            log_pass(store, "sim", bundle.id)
    store.close()
    return site, ids


def _state(site) -> tuple:
    store = Store(site, create=False)
    try:
        return [e.hash for e in entries(store)], store.all_pointers()
    finally:
        store.close()


def _refused(result, site, why: str) -> None:
    """One line naming the store and what sqlite said, exit 2, nothing on stdout."""
    assert result.exit_code == 2, result.output
    assert result.stdout == ""
    assert result.stderr == f"error: --site {site}: cannot write {STORE_FILE} ({why}); nothing changed\n"


def _whole(site, before: tuple) -> None:
    assert _state(site) == before
    assert verify_log(Store(site, create=False)) == []
    assert cli("verify", "--site", str(site)).exit_code == 0


@pytest.mark.parametrize("condition", [full, read_only])
def test_promote_on_a_store_that_cannot_be_written_is_one_line_and_moves_nothing(tmp_path, condition):
    site, ids = _site(tmp_path)
    before = _state(site)
    with condition(site) as why:
        result = cli("promote", ids["v1"], "--site", str(site), "--cell", CELL, "--to", "sim")
    _refused(result, site, why)
    _whole(site, before)


@pytest.mark.parametrize("condition", [full, read_only])
def test_rollback_on_a_store_that_cannot_be_written_is_one_line_and_moves_nothing(tmp_path, condition):
    site, _ = _site(tmp_path, passed=("v1", "v2"))
    before = _state(site)
    with condition(site) as why:
        result = cli("rollback", "--site", str(site), "--cell", CELL, "--stage", "sim")
    _refused(result, site, why)
    _whole(site, before)


@pytest.mark.parametrize("condition", [full, read_only])
def test_a_gates_entry_the_store_cannot_take_is_a_release_error_and_logs_nothing(tmp_path, condition):
    site, ids = _site(tmp_path, passed=("v1",))
    before = _state(site)
    with condition(site) as why, pytest.raises(ReleaseError, match=f"cannot write {STORE_FILE} \\({why}\\)"):
        store = Store(site)  # opened under the condition: sqlite reads the header as it opens the store
        log_pass(store, "sim", ids["v1"])
    store.close()
    _whole(site, before)


@pytest.mark.parametrize("condition", [full, read_only])
def test_any_write_in_a_transaction_is_a_release_error_even_one_past_store_write(tmp_path, condition):
    site, _ = _site(tmp_path, passed=("v1",))
    before = _state(site)
    with condition(site) as why, pytest.raises(ReleaseError, match=f"cannot write {STORE_FILE} \\({why}\\)"):
        store = Store(site)
        with store.transaction():
            store.db.execute("INSERT OR REPLACE INTO meta VALUES ('note', 'x')")
    assert store.meta("note") is None
    store.close()
    _whole(site, before)
