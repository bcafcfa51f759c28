"""`record to-lerobot` of a record its run is still writing names the cycle in progress as still running: it said
"its end was lost" of it, as of a cycle whose end marker a damaged chunk took."""

from __future__ import annotations

import subprocess
import sys

import pytest
from record_synth import record
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.record.scan import scan
from cellguard.record.writer import RECORD_FILE

runner = CliRunner()
# holds an exclusive flock on a folder, as a run does (folder_lock.hold), until its stdin closes
HOLDER = ("import fcntl, os, sys; fd = os.open(sys.argv[1], os.O_RDONLY | os.O_DIRECTORY); "
          "fcntl.flock(fd, fcntl.LOCK_EX); print('held', flush=True); sys.stdin.read()")


@pytest.fixture
def cut(tmp_path):
    """A record of 4 cycles cut inside its last chunk, before the last cycle's end marker, as a run leaves it."""
    record(tmp_path / "whole", 4, 300)
    data = (tmp_path / "whole" / RECORD_FILE).read_bytes()
    last = scan(tmp_path / "whole" / RECORD_FILE).chunks[-1]
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / RECORD_FILE).write_bytes(data[:last.offset + last.length // 2])
    return tmp_path / "run"


def test_the_cycle_in_progress_of_a_record_being_written_is_still_running(cut, tmp_path):
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(cut)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              text=True)
    try:
        assert holder.stdout.readline() == "held\n"
        result = runner.invoke(app, ["record", "to-lerobot", str(cut), "-o", str(tmp_path / "lr")])
    finally:
        holder.stdin.close()
        holder.wait()
    assert result.exit_code == 0, result.output
    assert (f"skipped cycle 3: still running (the record is still being written by a running process "
            f"(pid {holder.pid}))") in result.output.splitlines()
    assert "end was lost" not in result.output


def test_the_same_cycle_of_a_record_no_run_writes_lost_its_end(cut, tmp_path):
    result = runner.invoke(app, ["record", "to-lerobot", str(cut), "-o", str(tmp_path / "lr")])
    assert result.exit_code == 1, result.output
    assert "skipped cycle 3: its end was lost" in result.output.splitlines()
