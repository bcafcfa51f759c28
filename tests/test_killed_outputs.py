"""A command killed outright (SIGKILL, the OOM killer, a power switch) runs no clean-up. Killed during its final move,
``record to-lerobot`` left half a dataset at -o (data/ without meta/) and ``record recover`` an index without a
record, and every rerun refused the filled folder until it was removed by hand; every killed write of an output file
left its hidden temporary file (``.NAME.PID.tmp``, as large as the output) beside it for good. The next run of the
same command takes out exactly what the killed one made, and nothing that a live one or anyone else put there."""

from __future__ import annotations

import errno
import fcntl
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from cli_util import one_error
from run_copies import recorded, run  # noqa: F401 (fixtures)
from typer.testing import CliRunner

from cellguard import output
from cellguard.cli import app
from cellguard.output import write_output
from cellguard.record import recovery
from cellguard.record.reader import open_record

runner = CliRunner()

# The command in a process of its own that SIGKILLs itself right after its first ``call`` (rename: Path.rename,
# link: os.link, fsync: os.fsync) whose target is named argv[2] ("*": any): where a kill lands on a slow disk.
KILLED = """
import os, pathlib, sys
call, name = sys.argv[1], sys.argv[2]
owner = pathlib.Path if call == "rename" else os
real = getattr(owner, call)
def killed(*args, **kwargs):
    result = real(*args, **kwargs)
    if name == "*" or os.path.basename(str(args[1])) == name:
        os.kill(os.getpid(), 9)
    return result
setattr(owner, call, killed)
from cellguard.cli import app
app(sys.argv[3:], prog_name="cellguard")
"""


def _killed(call: str, name: str, *args) -> None:
    """Run the command ``args``, killed right after its first ``call`` onto ``name``."""
    proc = subprocess.run([sys.executable, "-c", KILLED, call, name, *map(str, args)], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == -signal.SIGKILL, proc.stderr


def _names(folder: Path) -> list[str]:
    return sorted(os.listdir(folder))


@pytest.mark.parametrize("made", [True, False])
def test_a_to_lerobot_killed_between_data_and_meta_is_taken_out_by_the_rerun(run, tmp_path, made):
    out = tmp_path / "lr" / "ds"
    (tmp_path / "lr").mkdir()
    (tmp_path / "lr" / "keep.txt").write_text("mine\n")
    if not made:
        out.mkdir()
    _killed("rename", "data", "record", "to-lerobot", run, "-o", out)
    assert _names(out) == ["data"]  # half a dataset, its staging folder beside it
    result = runner.invoke(app, ["record", "to-lerobot", str(run), "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert _names(tmp_path / "lr") == ["ds", "keep.txt"] and _names(out) == ["data", "meta"]
    assert json.loads((out / "meta" / "info.json").read_text())["total_episodes"] == 6


def test_what_replaced_a_killed_to_lerobots_part_is_never_taken_out(run, tmp_path):
    """Only the very folder the killed export moved is removed: data/ put there by anyone else stays, and the folder
    is refused as filled."""
    out = tmp_path / "ds"
    _killed("rename", "data", "record", "to-lerobot", run, "-o", out)
    os.rename(out / "data", tmp_path / "moved-away")
    (out / "data").mkdir()
    (out / "data" / "mine.txt").write_text("mine\n")
    line = one_error(runner.invoke(app, ["record", "to-lerobot", str(run), "-o", str(out)]))
    assert line == f"error: -o {out}: exists and is not empty; give a new folder"
    assert (out / "data" / "mine.txt").read_text() == "mine\n" and _names(out) == ["data"]
    assert _names(tmp_path) == ["ds", "moved-away", "run"]  # the killed export's staging folder cleared


def test_a_recover_killed_during_its_move_is_taken_out_by_the_rerun(run, tmp_path):
    target = tmp_path / "T"
    _killed("link", "*", "record", "recover", run, "-o", target)
    assert "record.mcap" not in os.listdir(target) and (target / "index").is_dir()  # an index without a record
    result = runner.invoke(app, ["record", "recover", str(run), "-o", str(target)])
    assert result.exit_code == 0, result.output
    assert _names(target) == ["index", "record.mcap"]
    with open_record(target) as rec:
        assert [c.cycle for c in rec.cycles()] == list(range(6))


def test_a_file_that_replaced_one_a_killed_recover_moved_is_never_taken_out(run, tmp_path):
    target = tmp_path / "T"
    _killed("link", "*", "record", "recover", run, "-o", target)
    moved = next(p for p in (target / "index").rglob("*") if p.is_file())
    moved.unlink()
    moved.write_bytes(b"mine")
    line = one_error(runner.invoke(app, ["record", "recover", str(run), "-o", str(target)]))
    assert line == f"error: -o {target}: exists and is not empty; give a new folder"
    assert moved.read_bytes() == b"mine" and _names(target) == ["index"]


def test_a_recover_whose_move_fails_leaves_nothing(run, tmp_path, monkeypatch):
    """A link that failed after the index was moved left the index without its record."""
    link = os.link

    def failing(src, dst, *args, **kwargs):
        if Path(dst).name == "record.mcap":
            raise OSError(errno.EIO, "Input/output error")
        return link(src, dst, *args, **kwargs)

    monkeypatch.setattr(recovery.os, "link", failing)
    line = one_error(runner.invoke(app, ["record", "recover", str(run), "-o", str(tmp_path / "T")]))
    assert line == f"error: {tmp_path / 'T'}: cannot write the recovered record (Input/output error)"
    assert _names(tmp_path) == ["run"]


def _temporaries(folder: Path) -> list[str]:
    return [name for name in os.listdir(folder) if name.endswith(".tmp")]


def test_the_temporary_file_of_a_killed_write_is_removed_by_the_next(run, tmp_path):
    out = tmp_path / "ex"
    _killed("fsync", "*", "record", "export", run, "-o", out / "t.csv")
    assert len(_temporaries(out)) == 1 and "t.csv" not in os.listdir(out)  # the whole table, under its hidden name
    result = runner.invoke(app, ["record", "export", str(run), "-o", str(out / "t.csv")])
    assert result.exit_code == 0, result.output
    assert _names(out) == ["t.csv"]


def test_the_temporary_file_of_a_live_write_is_kept(tmp_path):
    """A write still going on holds its temporary file's lock: another write of the same file leaves it be."""
    live = tmp_path / ".t.csv.4000001.tmp"
    live.write_bytes(b"being written")
    fd = os.open(live, os.O_WRONLY)
    fcntl.flock(fd, fcntl.LOCK_EX)
    try:
        write_output(tmp_path / "t.csv", "rows", "-o")
    finally:
        os.close(fd)
    assert _names(tmp_path) == [live.name, "t.csv"] and live.read_bytes() == b"being written"


def test_a_live_write_outlasts_another_write_of_the_same_file(tmp_path):
    """The other process's temporary file is written, locked, under its name until renamed into place."""
    go = tmp_path / "go"
    held = ("import sys, time; from pathlib import Path; from cellguard.output import atomic_file\n"
            "with atomic_file(Path(sys.argv[1]), '-o') as f:\n"
            "    f.write(b'first'); Path(sys.argv[2]).touch()\n"
            "    while Path(sys.argv[2]).exists(): time.sleep(0.02)\n")
    proc = subprocess.Popen([sys.executable, "-c", held, str(tmp_path / "t.csv"), str(go)])
    try:
        while not go.exists():
            assert proc.poll() is None
            time.sleep(0.02)
        write_output(tmp_path / "t.csv", "second", "-o")
        assert len(_temporaries(tmp_path)) == 1  # the live one's, kept
    finally:
        go.unlink()
    assert proc.wait(timeout=60) == 0
    assert _names(tmp_path) == ["t.csv"] and (tmp_path / "t.csv").read_text() == "first"


def test_a_temporary_file_taken_before_it_was_locked_is_made_again(tmp_path, monkeypatch):
    """Another write may find the new file before its lock is taken and remove it as a killed one's: the data then
    went to a file no name reaches and the rename failed. The file is looked up again once locked."""
    flock, taken = output.fcntl.flock, []

    def another_write_first(fd, operation):
        if not taken:
            taken.extend(_temporaries(tmp_path))
            os.unlink(tmp_path / taken[0])
        return flock(fd, operation)

    monkeypatch.setattr(output.fcntl, "flock", another_write_first)
    write_output(tmp_path / "t.csv", "rows", "-o")
    assert taken and _names(tmp_path) == ["t.csv"] and (tmp_path / "t.csv").read_text() == "rows"


def test_without_locks_a_temporary_file_is_kept(tmp_path, monkeypatch):
    """Where the filesystem offers no flock, a temporary file is never known stale: it is left as it is."""
    stale = tmp_path / ".t.csv.4000001.tmp"
    stale.write_bytes(b"killed")

    def no_locks(fd, operation):
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(output.fcntl, "flock", no_locks)
    write_output(tmp_path / "t.csv", "rows", "-o")
    assert _names(tmp_path) == [stale.name, "t.csv"] and (tmp_path / "t.csv").read_text() == "rows"


@pytest.mark.parametrize("name", [".t.csv.4000001.tmp/", ".t.csv.x1.tmp", ".u.csv.4000001.tmp", "t.csv.1.tmp"])
def test_only_a_regular_temporary_file_of_the_same_output_is_removed(tmp_path, name):
    """A folder of that name, or the temporary file of another output (or not one at all), is kept."""
    kept = tmp_path / name.rstrip("/")
    kept.mkdir() if name.endswith("/") else kept.write_bytes(b"other")
    write_output(tmp_path / "t.csv", "rows", "-o")
    assert _names(tmp_path) == sorted([kept.name, "t.csv"])
