"""``run --overwrite`` whose start fails keeps the record it was to replace. The old ``record.mcap``, its index parts
and the files made from it (``summary.json``, ``report.html``, ``baseline.json``, replay pages) were unlinked before
the new record was built, so a disk without room for the header, no memory for the ring, no process forked for the
writer or a failure after the fork lost them, and the line said "nothing was run". The new record now starts as a
hidden file and takes the old one's place only once its writer process runs (``Recorder.place``): a SIGKILL at any
moment leaves the old record whole or the new one readable, never neither. The files made from the old record are set
aside (``replaced``) before the rename, not removed: a kill or a failed rename there lost them."""

from __future__ import annotations

import errno
import gc
import hashlib
import multiprocessing
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml
from cli_util import one_error
from run_copies import small_tmpfs
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.control.events import EventKind
from cellguard.errors import RecordError
from cellguard.record import folder_lock
from cellguard.record.index import connect
from cellguard.record.reader import open_record
from cellguard.record.session import RESERVE_BYTES, RunRecording
from cellguard.record.writer import INDEX_DIR, RECORD_FILE, STARTING_FILE
from cellguard.runtime.loop import Run
from cellguard.scenario import load_scenario

runner = CliRunner()
ONE_CYCLE = {"cell": "arm-pick-place", "seed": 7, "acceptance_cycles": 1, "production_cycles": 0}
MADE_FROM_IT = {"report.html": "<html>the old run</html>", "baseline.json": '{"bound_to": "the old run"}',
                "replay-cycle-0.html": "<html>the old run's cycle 0</html>"}


@pytest.fixture(scope="module")
def original(tmp_path_factory):
    """A one-cycle run folder with files made from its record beside it, and its scenario."""
    root = tmp_path_factory.mktemp("original")
    scenario = root / "one.yaml"
    scenario.write_text(yaml.safe_dump(ONE_CYCLE))
    result = runner.invoke(app, ["run", str(scenario), "--out", str(root / "run")])
    assert result.exit_code == 0, result.output
    for name, text in MADE_FROM_IT.items():
        (root / "run" / name).write_text(text)
    return root / "run", scenario


@pytest.fixture
def old(original, tmp_path):
    """A copy of the original run folder (its files as they were, the record's id included), and the scenario."""
    shutil.copytree(original[0], tmp_path / "run")
    return tmp_path / "run", original[1]


def digests(folder: Path) -> dict[str, str]:
    """Every file under ``folder``, hidden ones included, by its bytes."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def record_id(folder: Path) -> str:
    with open_record(folder) as record:
        return record.record_id


def assert_whole(folder: Path, record: str, index: bool = True) -> None:
    """``folder``'s record is ``record``, finished and intact, with an index of its own that reads."""
    with open_record(folder) as rec:
        assert rec.record_id == record and rec.health().ok and rec.writing is None
    if index:
        assert connect(folder / INDEX_DIR, record_id=record).execute("SELECT count(*) FROM cycles").fetchone() == (1,)


def writers() -> list:
    """This process's recorder writer processes still running."""
    return [p for p in multiprocessing.active_children() if p.name == "cellguard-recorder"]


def wait_for_release(folder: Path, timeout_s: float = 60.0) -> None:
    """Until no process (a writer left by a killed run) holds ``folder``."""
    end = time.monotonic() + timeout_s
    while folder_lock.holder(folder) is not None:
        assert time.monotonic() < end, f"{folder} is still held"
        time.sleep(0.05)


def no_space(path: Path):
    """An opener whose file takes no byte: the disk is full."""
    class Full:
        def __init__(self):
            self.f = open(path, "xb")

        def write(self, data):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        def __getattr__(self, name):
            return getattr(self.f, name)
    return Full()


def failing_start(monkeypatch, where: str) -> None:
    """Make the next recording's start fail ``where``: no room for the header, no process forked, or the record
    cannot be renamed into place (after the writer process was forked)."""
    if where == "header":
        start = RunRecording.start.__func__
        monkeypatch.setattr(RunRecording, "start", classmethod(lambda cls, *a, **k: start(cls, *a, opener=no_space,
                                                                                          **k)))
    elif where == "fork":
        def no_fork():
            raise BlockingIOError(errno.EAGAIN, os.strerror(errno.EAGAIN))
        monkeypatch.setattr(os, "fork", no_fork)
    else:
        replace = os.replace

        def no_rename(source, target, **kwargs):
            if Path(target).name == RECORD_FILE:
                raise OSError(errno.EIO, os.strerror(errno.EIO))
            return replace(source, target, **kwargs)
        monkeypatch.setattr(os, "replace", no_rename)


@pytest.mark.parametrize("where, why", [("header", "no space or no access"),
                                        ("fork", "BlockingIOError: Resource temporarily unavailable"),
                                        ("placing", "EIO: Input/output error")])
def test_a_failed_start_of_overwrite_keeps_the_old_record_and_what_was_made_from_it(old, monkeypatch, where, why):
    out, scenario = old
    before, kept = digests(out), record_id(out)
    failing_start(monkeypatch, where)
    line = one_error(runner.invoke(app, ["run", str(scenario), "--out", str(out), "--overwrite"]))
    assert line == f"error: {out / RECORD_FILE}: cannot start the record ({why}); nothing was run"
    assert digests(out) == before  # byte for byte, and nothing of the failed start (no hidden file)
    assert_whole(out, kept)
    assert not writers()
    monkeypatch.undo()  # the folder takes the next --overwrite, which replaces it all
    assert runner.invoke(app, ["run", str(scenario), "--out", str(out), "--overwrite"]).exit_code == 0
    assert record_id(out) != kept and not any((out / name).exists() for name in MADE_FROM_IT)
    assert_whole(out, record_id(out))
    assert sorted(p.name for p in out.iterdir()) == [INDEX_DIR, RECORD_FILE, "summary.json"]


def test_a_full_disk_keeps_the_old_record_on_overwrite(old):
    """On a real tmpfs with room for the reserve and not for the new header: the old record was unlinked first, and
    its room let the run go ahead in its place."""
    out, scenario = old
    with small_tmpfs(out.parent / "disk", "1m") as disk:
        shutil.copytree(out, disk / "run")
        before, kept = digests(disk / "run"), record_id(disk / "run")
        room = os.statvfs(disk)
        free = room.f_bavail * room.f_frsize - (RESERVE_BYTES[0] + RESERVE_BYTES[1]) - 4096
        (disk / "filler").write_bytes(bytes(free))
        result = subprocess.run([sys.executable, "-c", "from cellguard.cli import app; app()", "run", str(scenario),
                                 "--out", str(disk / "run"), "--overwrite"], capture_output=True, text=True,
                                timeout=600)
        assert result.returncode == 2, result.stderr
        assert result.stderr.splitlines() == [f"error: {disk / 'run' / RECORD_FILE}: cannot start the record (no "
                                              f"space or no access); nothing was run"]
        assert digests(disk / "run") == before
        assert_whole(disk / "run", kept)


def test_a_failure_after_the_fork_leaves_no_writer_behind(old):
    """A start that failed after the writer process was forked left it running: it held the folder (the next start
    was refused as busy), the collector stayed frozen, and at exit it finished the record the start had removed and
    wrote its index beside none."""
    out, scenario = old
    before, kept = digests(out), record_id(out)
    run = Run(load_scenario(scenario), realtime=True)
    start = threading.Thread.start

    def no_feeder(thread):
        if thread.name == "cellguard-record-feeder":
            raise RuntimeError("can't start new thread")
        start(thread)
    try:
        threading.Thread.start = no_feeder
        try:
            with pytest.raises(RecordError,
                               match="'cellguard-record-feeder' could not start \\(can't start new thread"):
                RunRecording.start(out, run, replace=True)
        finally:
            threading.Thread.start = start
        assert not writers()
        assert gc.get_freeze_count() == 0
        assert folder_lock.holder(out) is None
        assert digests(out) == before
        assert_whole(out, kept)
    finally:
        run.close()


KILLED_RUN = """
import os, signal, sys
import multiprocessing.context
from cellguard.cli import app
from cellguard.record.writer import Recorder

where, scenario, out = sys.argv[1:]
def kill(*args):
    os.kill(os.getpid(), signal.SIGKILL)
if where == "before the fork":
    multiprocessing.context.ForkProcess.start = kill
elif where == "before the record is placed":
    Recorder.place = kill
else:
    place = Recorder.place
    Recorder.place = lambda self: (place(self), kill())
app(["run", scenario, "--out", out, "--overwrite"])
"""


@pytest.mark.parametrize("where", ["before the fork", "before the record is placed", "once the record is placed"])
def test_a_start_killed_at_any_point_leaves_the_old_record_or_the_new_one(old, where):
    out, scenario = old
    before, kept = digests(out), record_id(out)
    done = subprocess.run([sys.executable, "-c", KILLED_RUN, where, str(scenario), str(out)], capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == -signal.SIGKILL, done.stderr
    wait_for_release(out)  # the writer, if forked, ends on its own
    if where == "once the record is placed":  # the new record, which says its run was lost; none of the old
        with open_record(out) as record:
            assert record.record_id != kept and record.health().ok
            assert [e.kind for e in record.events()] == [EventKind.RUN_PROCESS_LOST]
        assert not any((out / name).exists() for name in [*MADE_FROM_IT, "summary.json"])
        return
    after = digests(out)
    assert {name: after.get(name) for name in before} == before
    assert_whole(out, kept)
    # killed before its writer was forked, the start leaves its hidden header-only file (and the reserve); a writer
    # removes them itself
    assert set(after) - set(before) == ({STARTING_FILE, ".cellguard-reserve"} if where == "before the fork" else set())
    assert runner.invoke(app, ["run", str(scenario), "--out", str(out), "--overwrite"]).exit_code == 0
    assert sorted(p.name for p in out.iterdir()) == [INDEX_DIR, RECORD_FILE, "summary.json"]


# SIGKILL inside ``Recorder.place``: the old record's index parts and the files made from it were removed before the
# rename, so a kill there left the old record with an empty index/ and no summary, report or baseline
KILLED_PLACE = """
import os, sys
from pathlib import Path
from cellguard.cli import app

where, scenario, out = sys.argv[1:]
replace = os.replace

def killed(source, target, **kwargs):  # before the record's rename, or just after it
    if Path(target).name == "record.mcap":
        if where == "after the record's rename":
            replace(source, target, **kwargs)
        os.kill(os.getpid(), 9)
    return replace(source, target, **kwargs)

os.replace = killed
app(["run", scenario, "--out", out, "--overwrite"])
"""


@pytest.mark.parametrize("where", ["before the record's rename", "after the record's rename"])
def test_a_start_killed_while_placing_its_record_loses_nothing(old, where):
    """Killed before the record's rename: the old record with every file made from it; after it: the new record,
    the old files beside it telling they are not its own (the index and the baseline name their record) until the
    next --overwrite."""
    out, scenario = old
    before, kept = digests(out), record_id(out)
    done = subprocess.run([sys.executable, "-c", KILLED_PLACE, where, str(scenario), str(out)], capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == -signal.SIGKILL, done.stderr
    wait_for_release(out)
    after = digests(out)
    if where == "before the record's rename":
        assert {name: after.get(name) for name in before} == before
        assert_whole(out, kept)
    else:
        new = record_id(out)
        assert new != kept and {name: after.get(name) for name in before if name != RECORD_FILE} == {
            name: digest for name, digest in before.items() if name != RECORD_FILE}  # nothing lost, none taken as its
        assert_whole(out, new, index=False)  # a lost run: the writer finished it alone
        query = runner.invoke(app, ["record", "query", str(out), "select count(*) from cycles"])
        assert query.exit_code == 2 and f"not this record's {new}" in " ".join(query.output.split())
    assert runner.invoke(app, ["run", str(scenario), "--out", str(out), "--overwrite"]).exit_code == 0
    assert sorted(p.name for p in out.iterdir()) == [INDEX_DIR, RECORD_FILE, "summary.json"]


def test_a_record_that_cannot_be_renamed_keeps_every_file_made_from_the_old_one(old):
    """A real rename that fails: a folder at ``record.mcap`` (EISDIR), and an immutable record (EPERM) where the
    filesystem and the user allow ``chattr +i``. The files beside it were removed first, and the line said "nothing was
    run"."""
    out, scenario = old
    before = digests(out)
    record = (out / RECORD_FILE).read_bytes()
    (out / RECORD_FILE).unlink()
    (out / RECORD_FILE).mkdir()
    there = digests(out)
    line = one_error(runner.invoke(app, ["run", str(scenario), "--out", str(out), "--overwrite"]))
    assert line == f"error: {out / RECORD_FILE}: cannot start the record (EISDIR: Is a directory); nothing was run"
    assert digests(out) == there
    (out / RECORD_FILE).rmdir()
    (out / RECORD_FILE).write_bytes(record)
    if subprocess.run(["chattr", "+i", str(out / RECORD_FILE)], capture_output=True).returncode:
        pytest.skip("chattr +i is not allowed here")
    try:
        line = one_error(runner.invoke(app, ["run", str(scenario), "--out", str(out), "--overwrite"]))
    finally:
        subprocess.run(["chattr", "-i", str(out / RECORD_FILE)], check=True)
    assert line == (f"error: {out / RECORD_FILE}: cannot start the record (EPERM: Operation not permitted); nothing "
                    f"was run")
    assert digests(out) == before


# a recording's start with the longest pre-trigger window (a 47 MB ring) under an address-space limit of the
# process's size plus ``margin`` rings, from the start's beginning to its end
LIMITED_RUN = """
import resource, sys
from cellguard.cli import app
from cellguard.record.session import RunRecording
from cellguard.record.writer import RecordConfig

margin, scenario, out = float(sys.argv[1]), sys.argv[2], sys.argv[3]
start = RunRecording.start.__func__
ring = (300_000 + 4 * 100 + 20 + 2000) * (8 + 4 + 4 * 6 * 6)

def limited(cls, *args, **kwargs):
    size = next(int(line.split()[1]) * 1024 for line in open("/proc/self/status") if line.startswith("VmSize:"))
    was = resource.getrlimit(resource.RLIMIT_AS)
    resource.setrlimit(resource.RLIMIT_AS, (size + int(margin * ring), was[1]))
    try:
        return start(cls, *args, **{**kwargs, "config": RecordConfig(pre_trigger_s=300.0)})
    finally:  # the run itself has all the memory it had
        resource.setrlimit(resource.RLIMIT_AS, was)
RunRecording.start = classmethod(limited)
app(["run", scenario, "--out", out, "--overwrite"])
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/status")
@pytest.mark.parametrize("margin", [0.5, 1.5])
def test_the_ring_is_built_once_and_no_memory_for_it_keeps_the_old_record(old, margin):
    """The ring is made once, in the memory shared with the writer: the start took about three rings (a private one,
    then the shared one and a buffer of zeros to fill it), so 1.5 rings more than the process ran out."""
    out, scenario = old
    before, kept = digests(out), record_id(out)
    done = subprocess.run([sys.executable, "-c", LIMITED_RUN, str(margin), str(scenario), str(out)],
                          capture_output=True, text=True, timeout=600, env={**os.environ, "PYTHONWARNINGS": "ignore"})
    if margin > 1:
        assert done.returncode == 0, done.stderr
        assert record_id(out) != kept
        return
    assert done.returncode == 2 and done.stderr.splitlines() == [
        f"error: {out / RECORD_FILE}: cannot start the record (OSError: Cannot allocate memory); nothing was run"]
    assert digests(out) == before
    assert_whole(out, kept)


def test_a_start_killed_before_its_writer_leaves_no_file_a_reader_takes_for_a_record(tmp_path, original):
    """The hidden file of a start killed before it placed its record is no record: a fresh folder holding only it
    takes a run without --overwrite, which removes it."""
    out = tmp_path / "fresh"
    out.mkdir()
    (out / STARTING_FILE).write_bytes(b"\x89MCAP0\r\n")
    with pytest.raises(RecordError, match="no record here"):
        open_record(out)
    assert runner.invoke(app, ["run", str(original[1]), "--out", str(out)]).exit_code == 0
    assert sorted(p.name for p in out.iterdir()) == [INDEX_DIR, RECORD_FILE, "summary.json"]
