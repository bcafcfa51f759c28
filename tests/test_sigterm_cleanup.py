"""SIGTERM or SIGHUP (``timeout``, ``kill``, a service's stop, a closed terminal) while an output is being written ends
the command as Ctrl-C does: its clean-up runs, exit 128 + the signal. Killed outright, an export left its hidden
temporary file (``.t.csv.PID.TOKEN.tmp``) or staging folder (``.ds.XXXXXXXX.partial``) beside the target for good, and
to-lerobot the -o folder it had made; the staging folder of one killed by SIGKILL is cleared by the next export."""

from __future__ import annotations

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

from cellguard.cli import app
from cellguard.record import lerobot_export
from cellguard.record.reader import open_record

runner = CliRunner()

# The command in a process of its own, its write held where a slow disk would hold it: ``where.name`` (a function
# that writes the output) does its work, then says so by making the file argv[1] and waits to be signalled.
HELD = """
import importlib, sys, time
from pathlib import Path
where, name = sys.argv[1].rsplit(".", 1)
module, ready = importlib.import_module(where), Path(sys.argv[2])
write = getattr(module, name)
def held(*args, **kwargs):
    write(*args, **kwargs)
    ready.touch()
    time.sleep(120)
setattr(module, name, held)
from cellguard.cli import app
app(sys.argv[3:], prog_name="cellguard")
"""
CSV_WRITE = "pyarrow.csv.write_csv"  # record export's whole table, into the temporary file
LEROBOT_WRITE = "cellguard.record.lerobot_export._write_json"  # meta/info.json, the data already in the staging folder


def _held(write: str, tmp_path: Path, *args) -> subprocess.Popen:
    """The command ``args`` started, once its write ``write`` is done and held."""
    ready = tmp_path / "ready"
    proc = subprocess.Popen([sys.executable, "-c", HELD, write, str(ready), *map(str, args)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not ready.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    assert ready.exists(), proc.communicate(timeout=10)
    return proc


def _signal(proc: subprocess.Popen, signum: int) -> str:
    """Send ``signum``; the command's stderr once it has ended."""
    proc.send_signal(signum)
    _, stderr = proc.communicate(timeout=60)
    return stderr


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_a_signal_during_record_export_leaves_the_earlier_file_and_no_temporary_one(run, tmp_path, signum):
    out = tmp_path / "ex"
    out.mkdir()
    earlier = runner.invoke(app, ["record", "export", str(run), "--cycle", "0", "-o", str(out / "t.csv")])
    assert earlier.exit_code == 0, earlier.output  # an earlier export: the one kind of file export replaces
    old = (out / "t.csv").read_bytes()
    proc = _held(CSV_WRITE, tmp_path, "record", "export", run, "-o", out / "t.csv")
    assert [p.name for p in out.iterdir() if p.name.startswith(".t.csv.")]  # the temporary file, written
    stderr = _signal(proc, signum)
    assert os.listdir(out) == ["t.csv"] and (out / "t.csv").read_bytes() == old
    assert proc.returncode == 128 + signum and "Traceback" not in stderr, stderr


@pytest.mark.parametrize("made", [True, False])
def test_sigterm_during_to_lerobot_leaves_no_staging_folder_and_no_folder_it_made(run, tmp_path, made):
    parent = tmp_path / "lr"
    parent.mkdir()
    (parent / "keep.txt").write_text("mine\n")
    if not made:
        (parent / "ds").mkdir()
    proc = _held(LEROBOT_WRITE, tmp_path, "record", "to-lerobot", run, "-o", parent / "ds")
    staging = [p for p in parent.iterdir() if p.name.endswith(".partial")]
    assert staging and any(staging[0].rglob("*.parquet"))  # the data, written
    stderr = _signal(proc, signal.SIGTERM)
    assert sorted(os.listdir(parent)) == (["keep.txt"] if made else ["ds", "keep.txt"])
    assert (parent / "keep.txt").read_text() == "mine\n"
    assert made or not any((parent / "ds").iterdir())  # the folder given stays, empty
    assert proc.returncode == 143 and "Traceback" not in stderr, stderr


def test_the_staging_folder_of_a_killed_to_lerobot_is_cleared_by_the_next(run, tmp_path):
    """SIGKILL runs no clean-up: its staging folder stayed for good beside every later dataset."""
    proc = _held(LEROBOT_WRITE, tmp_path, "record", "to-lerobot", run, "-o", tmp_path / "lr" / "ds")
    _signal(proc, signal.SIGKILL)
    assert proc.returncode == -signal.SIGKILL
    assert sum(p.name.endswith(".partial") for p in (tmp_path / "lr").iterdir()) == 1  # left by the kill
    result = runner.invoke(app, ["record", "to-lerobot", str(run), "-o", str(tmp_path / "lr" / "ds")])
    assert result.exit_code == 0, result.output
    assert os.listdir(tmp_path / "lr") == ["ds"]
    assert json.loads((tmp_path / "lr" / "ds" / "meta" / "info.json").read_text())["total_episodes"] == 6


def test_an_export_still_writing_into_the_folder_is_not_cleared(run, tmp_path):
    proc = _held(LEROBOT_WRITE, tmp_path, "record", "to-lerobot", run, "-o", tmp_path / "lr" / "ds")
    try:
        staging = [p for p in (tmp_path / "lr").iterdir() if p.name.endswith(".partial")]
        line = one_error(runner.invoke(app, ["record", "to-lerobot", str(run), "-o", str(tmp_path / "lr" / "ds")]))
        assert "another export is writing there" in line and staging[0].name in line
        assert staging[0].is_dir() and any(staging[0].rglob("*.parquet"))
    finally:
        _signal(proc, signal.SIGTERM)
    assert proc.returncode == 143 and os.listdir(tmp_path / "lr") == []


def test_an_interrupted_move_into_the_folder_takes_back_what_was_moved(run, tmp_path, monkeypatch):
    """Stopped between data/ and meta/, the folder the export made held data/ alone, not a dataset to LeRobot."""
    rename = Path.rename

    def interrupted(self, target):
        if Path(target).name == "meta":
            raise KeyboardInterrupt
        return rename(self, target)

    monkeypatch.setattr(Path, "rename", interrupted)
    with open_record(run) as rec, pytest.raises(KeyboardInterrupt):
        lerobot_export.export_lerobot(rec, tmp_path / "lr" / "ds")
    assert os.listdir(tmp_path / "lr") == []
