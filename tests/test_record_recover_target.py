"""``record recover -o NEW_DIR`` writes only into a new or empty folder: into one that held another run's index
and files, it deleted that run's index parts and mixed its own record in with the rest."""

from __future__ import annotations

import shutil

from cli_util import one_error
from run_copies import recorded, run  # noqa: F401 (fixtures)
from test_record_outputs import digests
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.record.reader import open_record

runner = CliRunner()


def test_a_folder_holding_another_runs_index_is_refused_and_left_as_it_is(run, tmp_path):
    target = tmp_path / "T"
    shutil.copytree(run / "index", target / "index")
    shutil.copy(run / "summary.json", target)
    (target / "notes.txt").write_text("notes\n")
    before = digests(target)
    line = one_error(runner.invoke(app, ["record", "recover", str(run), "-o", str(target)]))
    assert line == f"error: -o {target}: exists and is not empty; give a new folder"
    assert digests(target) == before and sorted(p.name for p in target.iterdir()) == ["index", "notes.txt",
                                                                                       "summary.json"]


def test_an_empty_folder_receives_the_copy_and_nothing_else(run, tmp_path):
    (tmp_path / "T").mkdir()
    result = runner.invoke(app, ["record", "recover", str(run), "-o", str(tmp_path / "T")])
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in (tmp_path / "T").iterdir()) == ["index", "record.mcap"]
    with open_record(tmp_path / "T") as rec:
        assert rec.health().ok and [c.cycle for c in rec.cycles()] == list(range(6))


def test_a_copy_that_appears_while_recovering_is_never_replaced(run, tmp_path, monkeypatch):
    """Two recoveries into one new folder both checked it empty, both ended 0, and the later rename replaced the
    first copy. Here the other copy lands while this one rebuilds its index: this one fails, that one stays."""
    from cellguard.record import recovery

    target = tmp_path / "T"
    rebuild = recovery._rebuild_index

    def the_other_lands(record, folder):
        rebuild(record, folder)
        (target / "record.mcap").write_bytes(b"the other copy")

    monkeypatch.setattr(recovery, "_rebuild_index", the_other_lands)
    line = one_error(runner.invoke(app, ["record", "recover", str(run), "-o", str(target)]))
    assert line == (f"error: -o {target}: record.mcap appeared there while the copy was made (another recovery?); "
                    f"nothing of it was replaced: give a new folder")
    assert [p.name for p in target.iterdir()] == ["record.mcap"]
    assert (target / "record.mcap").read_bytes() == b"the other copy"


def test_a_killed_recoverys_staging_folder_is_removed_and_a_live_ones_is_named(run, tmp_path):
    """After ``kill -9`` the rerun said only "exists and is not empty"."""
    from cellguard.record import folder_lock

    stale = tmp_path / "T" / ".recover-abc123.partial"
    (stale / "index").mkdir(parents=True)
    (stale / "record.mcap").write_bytes(b"half")
    live = folder_lock.hold(stale, "-o")  # its process still runs
    try:
        line = one_error(runner.invoke(app, ["record", "recover", str(run), "-o", str(tmp_path / "T")]))
    finally:
        folder_lock.release(live)
    assert line == (f"error: -o {tmp_path / 'T'}: another recovery is writing there (.recover-abc123.partial); wait "
                    f"for it to end or give another folder")
    assert (stale / "record.mcap").read_bytes() == b"half"
    result = runner.invoke(app, ["record", "recover", str(run), "-o", str(tmp_path / "T")])  # its process is gone
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in (tmp_path / "T").iterdir()) == ["index", "record.mcap"]


def test_a_run_writing_in_the_target_ends_the_recovery_in_one_line_not_a_silent_wait(run, tmp_path, monkeypatch):
    """A run started in the recovery's target (its staging folder did not count as a record) held the folder's lock
    for its whole life, and the recovery waited on it without a word: it waits a bounded time, then says why."""
    import time

    from cellguard.record import folder_lock, recovery

    monkeypatch.setattr(recovery, "MOVE_WAIT_S", 0.3)
    target = tmp_path / "T"
    target.mkdir()
    held = folder_lock.hold(target)  # as a run writing there holds it
    try:
        began = time.monotonic()
        line = one_error(runner.invoke(app, ["record", "recover", str(run), "-o", str(target)]))
        assert time.monotonic() - began < 60 and "another run is still writing its record there" in line
    finally:
        folder_lock.release(held)
    assert not (target / "record.mcap").exists()
