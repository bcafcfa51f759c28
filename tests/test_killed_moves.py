"""``to-lerobot`` and ``recover`` killed (SIGKILL) between the moves that fill their target: the rerun of the same
command was refused as "not empty" and the user had to pick the half-moved files out by hand. The rerun now takes out
exactly what the killed run had moved and makes the output again; a finished output, a file someone else put there,
a live run's files and the record read are never touched."""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

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


def test_what_someone_else_put_in_the_target_after_the_kill_is_kept(run, tmp_path):
    ds = tmp_path / "lr" / "ds"
    _killed("rename", "data", "record", "to-lerobot", run, "-o", ds)
    (ds / "notes.txt").write_text("mine")
    (ds / "data" / "mine.csv").write_text("also mine")
    code, out = _cli("record", "to-lerobot", run, "-o", ds)
    assert (code, out) == (2, f"error: -o {ds}: exists and is not empty; give a new folder\n")
    assert _files(ds) == {"notes.txt": b"mine", "data/mine.csv": b"also mine"}  # the killed run's parquet is gone
    assert os.listdir(tmp_path / "lr") == ["ds"]


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
