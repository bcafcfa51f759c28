"""``to-lerobot`` and ``recover`` killed (SIGKILL) between the moves that fill their target: the rerun of the same
command was refused as "not empty" and the user had to pick the half-moved files out by hand. The rerun now takes out
exactly what the killed run had moved and makes the output again, where the target holds nothing else; a finished
output, a target holding anything more (a file someone else put there or changed, a link), a live run's files and
the record read are never touched, nor anything when the note is damaged."""

from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from run_copies import recorded, run  # noqa: F401 (fixtures)
from typer.testing import CliRunner

from cellguard.cli import app

runner = CliRunner()

# The command in a process of its own that, right after its first ``call`` (rename: Path.rename, link: os.link) onto
# the name argv[2] ("*": any), is killed (argv[3] "kill") or waits once while the file argv[4] exists ("hold").
STOPPED = """
import os, pathlib, sys, time
call, name, how, flag = sys.argv[1:5]
owner = pathlib.Path if call == "rename" else os
real, done = getattr(owner, call), []
def stopped(*args, **kwargs):
    result = real(*args, **kwargs)
    if not done and name in ("*", os.path.basename(str(args[1]))):
        done.append(1)
        if how == "kill":
            os.kill(os.getpid(), 9)
        pathlib.Path(flag).touch()
        while pathlib.Path(flag).exists():
            time.sleep(0.02)
    return result
setattr(owner, call, stopped)
from cellguard.cli import app
app(sys.argv[5:], prog_name="cellguard")
"""


def _killed(call: str, name: str, *args) -> None:
    proc = subprocess.run([sys.executable, "-c", STOPPED, call, name, "kill", "-", *map(str, args)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == -signal.SIGKILL, proc.stderr


def _held(call: str, name: str, flag: Path, *args) -> subprocess.Popen:
    """The command, paused right after that move until ``flag`` is removed."""
    proc = subprocess.Popen([sys.executable, "-c", STOPPED, call, name, "hold", str(flag), *map(str, args)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    while not flag.exists():
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.02)
    return proc


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _cli(*args) -> tuple[int, str]:
    result = runner.invoke(app, list(map(str, args)))
    return result.exit_code, result.output


def test_to_lerobot_killed_between_its_moves_is_made_again_by_the_rerun(run, tmp_path):
    record = _files(run)
    ds = tmp_path / "lr" / "ds"
    _killed("rename", "data", "record", "to-lerobot", run, "-o", ds)
    assert sorted(os.listdir(ds)) == ["data"]  # meta/ still in the killed run's staging folder
    code, out = _cli("record", "to-lerobot", run, "-o", ds)
    assert code == 0, out
    assert os.listdir(tmp_path / "lr") == ["ds"] and sorted(os.listdir(ds)) == ["data", "meta"]
    assert json.loads((ds / "meta/info.json").read_text())["total_episodes"] == 6
    assert _files(run) == record


def test_recover_killed_between_its_moves_is_made_again_by_the_rerun(run, tmp_path):
    record = _files(run)
    target = tmp_path / "T"
    _killed("link", "*", "record", "recover", run, "-o", target)
    placed = [p for p in target.rglob("*") if p.is_file() and ".partial" not in str(p.relative_to(target))]
    assert len(placed) == 1 and placed[0].suffix == ".parquet"  # one index part; the record comes last
    code, out = _cli("record", "recover", run, "-o", target)
    assert code == 0, out
    assert sorted(os.listdir(target)) == ["index", "record.mcap"]
    assert sorted(_files(target / "index")) == sorted(_files(run / "index"))
    code, out = _cli("record", "info", target, "--json")
    assert code == 0 and json.loads(out)["health"]["recovered_from"], out
    assert _files(run) == record


def test_a_dataset_whose_every_part_had_moved_is_kept_whole(run, tmp_path):
    """Killed after its last move, before removing its empty staging folder: the dataset is finished; the rerun is
    refused as for any filled folder, and only the staging folder goes."""
    ds = tmp_path / "lr" / "ds"
    _killed("rename", "meta", "record", "to-lerobot", run, "-o", ds)
    dataset = _files(ds)
    code, out = _cli("record", "to-lerobot", run, "-o", ds)
    assert (code, out) == (2, f"error: -o {ds}: exists and is not empty; give a new folder\n")
    assert os.listdir(tmp_path / "lr") == ["ds"] and _files(ds) == dataset
    assert json.loads(dataset["meta/info.json"])["total_episodes"] == 6


def test_a_target_holding_anything_more_is_refused_and_nothing_touched_until_it_holds_nothing_else(run, tmp_path):
    """Files someone put in the target after the kill: the rerun took the killed run's parquet out from among them. It
    now touches nothing, the killed run's staging folder included, so that once they are gone the rerun still knows
    its files."""
    ds = tmp_path / "lr" / "ds"
    _killed("rename", "data", "record", "to-lerobot", run, "-o", ds)
    (ds / "notes.txt").write_text("mine")
    (ds / "data" / "mine.csv").write_text("also mine")
    before, lr = _files(ds), _files(tmp_path / "lr")
    [staging] = (tmp_path / "lr").glob(".ds.*.partial")
    code, out = _cli("record", "to-lerobot", run, "-o", ds)
    assert (code, out) == (2, _left(ds, staging))  # named: the user knows what it left, and where its files are told
    assert _files(ds) == before and _files(tmp_path / "lr") == lr and len(os.listdir(tmp_path / "lr")) == 2
    (ds / "notes.txt").unlink()
    (ds / "data" / "mine.csv").unlink()
    code, out = _cli("record", "to-lerobot", run, "-o", ds)
    assert code == 0, out
    assert os.listdir(tmp_path / "lr") == ["ds"]
    assert json.loads((ds / "meta/info.json").read_text())["total_episodes"] == 6


def test_an_export_stopped_while_a_file_appeared_in_its_target_keeps_its_note_for_the_rerun(run, tmp_path):
    """SIGTERM after data/ moved, a file of the user's in the target meanwhile: the take-back was refused and the
    staging folder removed all the same, so the moved data/ stayed for good and the rerun was refused."""
    ds, flag = tmp_path / "lr" / "ds", tmp_path / "paused"
    proc = _held("rename", "data", flag, "record", "to-lerobot", run, "-o", ds)
    (ds / "notes.txt").write_text("mine")
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=120) == 128 + signal.SIGTERM, proc.communicate()
    [staging] = (tmp_path / "lr").glob(".ds.*.partial")
    assert (staging / ".moved-files.json").is_file() and sorted(os.listdir(ds)) == ["data", "notes.txt"]
    (ds / "notes.txt").unlink()
    code, out = _cli("record", "to-lerobot", run, "-o", ds)
    assert code == 0, out
    assert os.listdir(tmp_path / "lr") == ["ds"] and sorted(os.listdir(ds)) == ["data", "meta"]
    assert json.loads((ds / "meta/info.json").read_text())["total_episodes"] == 6


def test_a_recovery_stopped_while_a_file_appeared_in_its_target_keeps_its_note_for_the_rerun(run, tmp_path):
    target, flag = tmp_path / "T", tmp_path / "paused"
    proc = _held("link", "*", flag, "record", "recover", run, "-o", target)
    (target / "notes.txt").write_text("mine")
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=120) == 128 + signal.SIGTERM, proc.communicate()
    [staging] = target.glob(".recover-*.partial")
    assert (staging / ".moved-files.json").is_file() and sorted(os.listdir(target)) == [staging.name, "index",
                                                                                         "notes.txt"]
    (target / "notes.txt").unlink()
    code, out = _cli("record", "recover", run, "-o", target)
    assert code == 0, out
    assert sorted(os.listdir(target)) == ["index", "record.mcap"]
    assert sorted(_files(target / "index")) == sorted(_files(run / "index"))


def test_a_live_export_between_its_moves_is_never_taken_over(run, tmp_path):
    ds, flag = tmp_path / "lr" / "ds", tmp_path / "paused"
    proc = _held("rename", "data", flag, "record", "to-lerobot", run, "-o", ds)
    try:
        code, out = _cli("record", "to-lerobot", run, "-o", ds)
        assert code == 2 and out.startswith(f"error: -o {ds}: another export is writing there (.ds."), out
        assert sorted(os.listdir(ds)) == ["data"] and len(os.listdir(tmp_path / "lr")) == 2
    finally:
        flag.unlink()
    assert proc.wait(timeout=120) == 0, proc.communicate()
    assert os.listdir(tmp_path / "lr") == ["ds"] and sorted(os.listdir(ds)) == ["data", "meta"]


def test_a_live_recovery_between_its_moves_is_never_taken_over(run, tmp_path):
    target, flag = tmp_path / "T", tmp_path / "paused"
    proc = _held("link", "*", flag, "record", "recover", run, "-o", target)
    try:
        code, out = _cli("record", "recover", run, "-o", target)
        assert code == 2 and out.startswith(f"error: -o {target}: another recovery is writing there (.recover-"), out
    finally:
        flag.unlink()
    assert proc.wait(timeout=120) == 0, proc.communicate()
    assert sorted(os.listdir(target)) == ["index", "record.mcap"]


def test_a_recovery_that_fails_in_its_moves_leaves_none_of_its_files(run, tmp_path, monkeypatch):
    """A full disk at the record's move left the index parts already linked in the target: a folder the rerun refused
    as not empty."""
    link = os.link

    def full_at_the_record(source, destination, *args, **kwargs):
        if Path(destination).name == "record.mcap":
            raise OSError(errno.ENOSPC, "No space left on device")
        return link(source, destination, *args, **kwargs)

    monkeypatch.setattr(os, "link", full_at_the_record)
    code, out = _cli("record", "recover", run, "-o", tmp_path / "T")
    monkeypatch.undo()
    assert code == 2 and "cannot write the recovered record (No space left on device)" in out, out
    assert not (tmp_path / "T").exists()  # it made the folder: nothing of it is left


NOT_EMPTY = "error: -o {}: exists and is not empty; give a new folder\n"


def _left(target: Path, staging: Path) -> str:
    """The refusal of ``target`` naming the ``staging`` folder a stopped run left, kept for its note."""
    return (f"error: -o {target}: exists and is not empty; give a new folder or empty it: a run stopped while moving "
            f"its files into it left {staging} (.moved-files.json there lists the files it moved); that folder goes "
            f"with the next run once the target is empty\n")


def _note(staging: Path, files: dict[str, Path], fields: int = 5) -> None:
    """A staging folder noting ``files`` (name in the target: the file whose identity is noted), as a run does;
    ``fields`` 3: the note of 55da705 (name, device, inode)."""
    staging.mkdir(parents=True, exist_ok=True)
    noted = [[name, st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns][:fields]
             for name, path in files.items() for st in [os.lstat(path)]]
    (staging / ".moved-files.json").write_text(json.dumps(noted))


@pytest.mark.parametrize("how", ["replaced", "copied onto"])
def test_a_dataset_of_the_users_where_the_killed_one_was_is_never_touched(run, tmp_path, how):
    """The user removed the half-filled target (the hidden staging folder beside it stayed) and put a dataset of their
    own there, or copied their own file onto the killed run's: the rerun deleted the user's file that had the noted
    inode (ext4 gives a freed inode to the next file made; a copy onto a file keeps it)."""
    theirs = tmp_path / "theirs"
    assert _cli("record", "to-lerobot", run, "-o", theirs)[0] == 0
    ds = tmp_path / "lr" / "ds"
    _killed("rename", "data", "record", "to-lerobot", run, "-o", ds)
    if how == "replaced":
        shutil.rmtree(ds)
        subprocess.run(["cp", "-r", str(theirs), str(ds)], check=True)  # as the user would; the freed inode reused
    else:
        (theirs / "data/chunk-000/file-000.parquet").write_bytes(b"my own parquet")
        shutil.copyfile(theirs / "data/chunk-000/file-000.parquet", ds / "data/chunk-000/file-000.parquet")
    before = _files(ds)
    code, out = _cli("record", "to-lerobot", run, "-o", ds)
    assert (code, out) == (2, NOT_EMPTY.format(ds)) and _files(ds) == before


def test_a_note_of_the_previous_format_names_its_folder_and_goes_once_the_target_is_empty(run, tmp_path):
    """A run killed under the code before the note held size and mtime noted [name, device, inode]: never read (an
    inode alone is reused), so the target was refused for good without a word of what was left, or where."""
    ds = tmp_path / "lr" / "ds"
    _killed("rename", "data", "record", "to-lerobot", run, "-o", ds)
    [staging] = (tmp_path / "lr").glob(".ds.*.partial")
    note = staging / ".moved-files.json"
    note.write_text(json.dumps([entry[:3] for entry in json.loads(note.read_text())]))
    before = _files(ds)
    for _ in range(2):
        assert _cli("record", "to-lerobot", run, "-o", ds) == (2, _left(ds, staging)) and _files(ds) == before
    shutil.rmtree(ds / "data")  # as the refusal says
    code, out = _cli("record", "to-lerobot", run, "-o", ds)
    assert code == 0 and os.listdir(tmp_path / "lr") == ["ds"], out
    assert json.loads((ds / "meta/info.json").read_text())["total_episodes"] == 6


@pytest.mark.parametrize("change", ["edited", "removed"])
def test_a_finished_dataset_the_user_changed_is_kept_whole(run, tmp_path, change):
    """Killed after its last move: finished. The user edited one file (a new inode, as ``sed -i`` makes) or removed
    one; the rerun read "fewer files in place than noted" as cut short and deleted the 4 others."""
    ds = tmp_path / "lr" / "ds"
    _killed("rename", "meta", "record", "to-lerobot", run, "-o", ds)
    info = ds / "meta" / "info.json"
    if change == "edited":
        edited = info.with_name("info.json.new")
        edited.write_text(info.read_text().replace('"fps"', '"fps" '))
        edited.replace(info)
    else:
        (ds / "meta" / "stats.json").unlink()
    before = _files(ds)
    code, out = _cli("record", "to-lerobot", run, "-o", ds)
    assert (code, out) == (2, NOT_EMPTY.format(ds)) and _files(ds) == before
    assert os.listdir(tmp_path / "lr") == ["ds"]  # the killed run's staging folder, of a finished dataset, is gone


@pytest.mark.parametrize("fields", [3, 5])
def test_a_note_naming_files_through_a_link_never_reaches_them(run, tmp_path, fields):
    """A note (damaged or crafted) naming ``l/record.mcap`` in a target whose ``l`` links to the record read: the rerun
    of recover deleted the source record, and to-lerobot a file outside its target. A link in the target is never
    followed: it is something else there, and the target is refused as it is."""
    record = _files(run)
    target = tmp_path / "T"
    target.mkdir()
    (target / "l").symlink_to(run)
    staging = target / ".recover-abcdefgh.partial"
    staging.mkdir()
    (staging / "record.mcap").write_bytes(b"copy")  # not yet moved: cut short
    _note(staging, {"l/record.mcap": run / "record.mcap", "record.mcap": staging / "record.mcap"}, fields)
    code, out = _cli("record", "recover", run, "-o", target)
    assert (code, out) == (2, _left(target, staging)) and _files(run) == record
    assert (target / "l").is_symlink() and sorted(os.listdir(target)) == [staging.name, "l"]

    outside = tmp_path / "outside"
    (outside / "sub").mkdir(parents=True)
    (outside / "precious.txt").write_text("mine")
    (outside / "sub" / "notes.txt").write_text("mine")
    ds = tmp_path / "lr" / "ds"
    ds.mkdir(parents=True)
    (ds / "keep").symlink_to(outside)
    staging = tmp_path / "lr" / ".ds.abcdefgh.partial"
    (staging / "meta").mkdir(parents=True)
    (staging / "meta" / "info.json").write_text("{}")
    _note(staging, {"keep/precious.txt": outside / "precious.txt", "keep/sub/notes.txt": outside / "sub/notes.txt",
                    "meta/info.json": staging / "meta/info.json"}, fields)
    code, out = _cli("record", "to-lerobot", run, "-o", ds)
    assert (code, out) == (2, _left(ds, staging))
    assert _files(outside) == {"precious.txt": b"mine", "sub/notes.txt": b"mine"} and (ds / "keep").is_symlink()


@pytest.mark.parametrize("note", [b'[["a\\u0000b", 1, 2, 3, 4]]', b'[["a", 1e400, 2, 3, 4]]',
                                  b'[["\\ud800", 1, 2, 3, 4]]', b'[["a", true, 2, 3, 4]]', b'[["../x", 1, 2, 3, 4]]',
                                  b'[["/x", 1, 2, 3, 4]]', b'[["", 1, 2, 3, 4]]', b'[["a", -1, 2, 3, 4]]',
                                  b'{"a": 1}', b"[" * 100_000, b"\xff\xfe", b'[["a", 1, 2]]'])
def test_a_damaged_note_is_refused_naming_its_folder_and_cleared_once_the_target_is_empty(run, tmp_path, note):
    """A NUL byte, 1e400 or a lone surrogate in the note were tracebacks."""
    ds = tmp_path / "lr" / "ds"
    ds.mkdir(parents=True)
    (ds / "mine.txt").write_text("mine")
    staging = tmp_path / "lr" / ".ds.abcdefgh.partial"
    (staging / "meta").mkdir(parents=True)
    (staging / "meta" / "info.json").write_text("{}")
    (staging / ".moved-files.json").write_bytes(note)
    code, out = _cli("record", "to-lerobot", run, "-o", ds)
    assert (code, out) == (2, _left(ds, staging)) and _files(ds) == {"mine.txt": b"mine"}
    assert sorted(os.listdir(tmp_path / "lr")) == [staging.name, "ds"]
    (ds / "mine.txt").unlink()  # nothing there for the note to tell: the killed run's folder goes, the export is made
    code, out = _cli("record", "to-lerobot", run, "-o", ds)
    assert code == 0 and os.listdir(tmp_path / "lr") == ["ds"], out


@pytest.mark.skipif(os.geteuid() != 0, reason="giving a folder to another user needs root")
def test_a_staging_folder_of_another_user_takes_nothing_back(run, tmp_path):
    """In a folder all may write to (/tmp), another user could put a staging folder beside the target whose note
    names the target's files as they are: the rerun would have deleted them."""
    ds = tmp_path / "lr" / "ds"
    (ds / "data").mkdir(parents=True)
    (ds / "data" / "mine.parquet").write_text("mine")
    staging = tmp_path / "lr" / ".ds.abcdefgh.partial"
    (staging / "meta").mkdir(parents=True)
    (staging / "meta" / "info.json").write_text("{}")
    _note(staging, {"data/mine.parquet": ds / "data/mine.parquet", "meta/info.json": staging / "meta/info.json"})
    for path in (staging, staging / ".moved-files.json"):
        os.chown(path, 1, 1)
    code, out = _cli("record", "to-lerobot", run, "-o", ds)
    assert (code, out) == (2, _left(ds, staging)) and _files(ds) == {"data/mine.parquet": b"mine"}
