"""A record its run is still writing: `record info` told it as truncated (exit 1) and `record recover` made a copy
labelled as recovered from a truncated record. The run holds its folder's lock (``record.folder_lock``) while it
writes, so a reader tells: "still being written by a running process (pid N)", exit 0 with a note where nothing
read so far was lost (diagnose and report say the same), and `record recover` refuses (exit 2, nothing written).
Readers only probe the lock: the writer keeps it."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from cli_util import FIXTURE_SHIFT_RUN, one_error, record_run
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import RecordError
from cellguard.record import folder_lock
from cellguard.record.reader import open_record
from cellguard.record.scan import scan
from cellguard.record.session import RunRecording
from cellguard.record.writer import RECORD_FILE
from cellguard.runtime import Run
from cellguard.scenario import load_scenario

runner = CliRunner()
# holds an exclusive flock on a folder, as a run does (folder_lock.hold), until its stdin closes
HOLDER = ("import fcntl, os, sys; fd = os.open(sys.argv[1], os.O_RDONLY | os.O_DIRECTORY); "
          "fcntl.flock(fd, fcntl.LOCK_EX); print('held', flush=True); sys.stdin.read()")


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    return record_run(tmp_path_factory.mktemp("run"), {**FIXTURE_SHIFT_RUN, "production_cycles": 6})


def _cut(finished: Path, folder: Path, chunk: int = -4) -> Path:
    """``folder`` holding the finished record cut inside its chunk ``chunk``, as its run left it mid-write."""
    data = (finished / RECORD_FILE).read_bytes()
    ref = scan(finished / RECORD_FILE).chunks[chunk]
    folder.mkdir()
    (folder / RECORD_FILE).write_bytes(data[:ref.offset + ref.length // 2])
    return folder


@contextmanager
def _held(folder: Path) -> Iterator[int]:
    """``folder`` held by another process, as a running run holds its folder; that process's pid."""
    process = subprocess.Popen([sys.executable, "-c", HOLDER, str(folder)], stdin=subprocess.PIPE,
                               stdout=subprocess.PIPE, text=True)
    try:
        assert process.stdout.readline() == "held\n"
        yield process.pid
    finally:
        process.stdin.close()
        process.wait()


@pytest.fixture
def live(finished, tmp_path):
    """A cut record whose folder another process holds: (folder, that process's pid)."""
    folder = _cut(finished, tmp_path / "live")
    with _held(folder) as pid:
        yield folder, pid


def test_info_on_a_record_being_written_says_so_and_exits_0(live):
    folder, pid = live
    result = runner.invoke(app, ["record", "info", str(folder)])
    assert result.exit_code == 0, result.output
    assert result.stderr.startswith(f"note: {folder}: still being written by a running process (pid {pid}): read "
                                    f"so far "), result.stderr
    assert "truncated" not in result.output and "recover" not in result.stderr
    health = json.loads(runner.invoke(app, ["record", "info", str(folder), "--json"]).stdout)["health"]
    assert health["writing"] == f"a running process (pid {pid})"
    assert health["damage"] == [] and not health["ok"]  # its unwritten end is no damage; the record is not whole


def test_recover_refuses_a_record_being_written_and_writes_nothing(live, tmp_path):
    folder, pid = live
    line = one_error(runner.invoke(app, ["record", "recover", str(folder), "-o", str(tmp_path / "copy")]))
    assert line.startswith(f"error: {folder}: still being written by a running process (pid {pid}); nothing was "
                           f"copied: wait for it to end"), line
    assert not (tmp_path / "copy").exists()


def test_diagnose_and_report_on_a_record_being_written_say_so_as_info_does(live, tmp_path):
    folder, pid = live
    said = f"still being written by a running process (pid {pid})"
    diagnosis = runner.invoke(app, ["diagnose", str(folder), "--json"])
    assert diagnosis.exit_code == 0, diagnosis.output
    assert json.loads(diagnosis.stdout)["record"]["status"].startswith(said)
    assert f"note: {folder}: {said}" in diagnosis.stderr and "truncated" not in diagnosis.stderr
    report = runner.invoke(app, ["report", str(folder), "-o", str(tmp_path / "r.html")])
    assert report.exit_code == 0, report.output
    assert f"note: {folder}: {said}" in report.stderr and "truncated" not in report.stderr, report.output
    assert said in (tmp_path / "r.html").read_text()


def test_a_record_being_written_with_no_chunk_yet_says_so(finished, tmp_path):
    folder = _cut(finished, tmp_path / "new", chunk=0)
    with _held(folder) as pid:
        line = one_error(runner.invoke(app, ["record", "info", str(folder)]))
    assert line == (f"error: {folder / RECORD_FILE}: still being written by a running process (pid {pid}), no chunk "
                    f"of it yet; wait for its first chunk or for the run to end")


def test_the_same_file_left_by_a_run_that_ended_is_truncated(finished, tmp_path):
    folder = _cut(finished, tmp_path / "left")
    result = runner.invoke(app, ["record", "info", str(folder)])
    assert result.exit_code == 1, result.output
    assert f"warning: {folder}: truncated: recovered " in result.stderr and "record recover" in result.stderr
    assert runner.invoke(app, ["record", "recover", str(folder), "-o", str(tmp_path / "copy")]).exit_code == 0


def test_a_record_read_during_a_real_run_is_told_as_being_written_and_the_run_keeps_its_lock(finished, tmp_path):
    run = Run(load_scenario(finished.parent / "scenario.yaml"))
    folder = tmp_path / "running"
    run.recording = RunRecording.start(folder, run)
    try:
        run.cycle()
        run.cycle()
        info = runner.invoke(app, ["record", "info", str(folder)])  # whether or not a chunk is on disk yet
        assert info.exit_code in (0, 2), info.output
        assert "still being written by a running process" in info.stderr and "truncated" not in info.stderr
        recover = runner.invoke(app, ["record", "recover", str(folder), "-o", str(tmp_path / "copy")])
        assert "still being written by a running process" in one_error(recover)
        with pytest.raises(RecordError, match="another run is still writing"):
            folder_lock.hold(folder)  # the readers' probes left the run's lock as it was
        run.cycle()
    finally:
        run.recording.close()
        run.close()
    with open_record(folder) as rec:
        assert rec.writing is None and rec.health().ok
    assert runner.invoke(app, ["record", "info", str(folder)]).exit_code == 0


def test_a_probe_of_a_free_folder_lets_go_of_it(tmp_path):
    assert folder_lock.holder(tmp_path) is None
    folder_lock.release(folder_lock.hold(tmp_path))  # free again: the probe's shared lock went with its descriptor


@pytest.mark.parametrize("link", ["view/record.mcap", "cell1-latest.mcap"])
def test_a_record_being_written_read_through_a_link_says_so(live, tmp_path, link):
    """The lock was looked for beside the link, not beside the record: truncated, exit 1, and recover copied it."""
    folder, pid = live
    path = tmp_path / link
    path.parent.mkdir(exist_ok=True)
    path.symlink_to(folder / RECORD_FILE)
    result = runner.invoke(app, ["record", "info", str(path)])
    assert result.exit_code == 0 and f"still being written by a running process (pid {pid})" in result.stderr


def test_nothing_is_left_beside_a_record_being_written(live, tmp_path):
    """report.html, baseline.json and fixes.json written beside it described a part of it once the run ended (the
    report still said "still being written")."""
    folder, _ = live
    refused = one_error(runner.invoke(app, ["report", str(folder)]))
    assert refused.startswith(f"error: {folder}: still being written by a running process") and "-o FILE" in refused
    assert runner.invoke(app, ["diagnose", str(folder), "--json"]).exit_code == 0
    assert sorted(p.name for p in folder.iterdir()) == [RECORD_FILE]


def test_a_reader_takes_no_lock_where_the_kernel_lists_them(tmp_path, monkeypatch):
    """Its shared lock, held a few microseconds, refused a run starting that instant (11 of 20,000 starts)."""
    if not Path("/proc/locks").exists():
        pytest.skip("no /proc/locks on this OS")
    taken = []
    monkeypatch.setattr(folder_lock.fcntl, "flock", lambda fd, op: taken.append(op))
    assert folder_lock.holder(tmp_path) is None and taken == []


def test_the_diagnosis_context_has_the_records_start(finished):
    """The report times events from it: without it, events of a run on wall time read seconds since boot."""
    from cellguard.diagnose.from_record import diagnose_record

    with open_record(finished) as rec:
        start = rec.start_ns
    assert diagnose_record(finished).context["start_ns"] == start


def test_a_run_writes_its_summary_while_it_still_holds_its_folder(tmp_path, monkeypatch):
    """The summary was written after the lock was let go: a run started there in between had it beside its own
    record."""
    import cellguard.runtime.loop as loop
    from cellguard.runtime import run_scenario
    from cellguard.scenario import parse_scenario

    seen, write = [], loop.write_output
    monkeypatch.setattr(loop, "write_output", lambda path, *a: (seen.append(folder_lock.holder(path.parent)),
                                                                write(path, *a))[1])
    run_scenario(parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 0}),
                 tmp_path / "out")
    assert len(seen) == 1 and seen[0] is not None and folder_lock.holder(tmp_path / "out") is None


def test_the_demo_holds_its_folder_until_its_report_is_written(tmp_path, monkeypatch):
    """Its report was written after the run let go of the folder: a run started there in between got a report of
    the demo's record, which it had replaced, beside its own."""
    import cellguard.cli.run as cli_run
    import cellguard.report.from_record as from_record

    scenario = tmp_path / "demo.yaml"
    scenario.write_text(json.dumps(FIXTURE_SHIFT_RUN))
    monkeypatch.setattr(cli_run, "DEMO_SCENARIO", scenario)
    seen, write = [], from_record.write_report
    monkeypatch.setattr(from_record, "write_report", lambda folder, **k: (seen.append(folder_lock.holder(folder)),
                                                                          write(folder, **k))[1])
    result = runner.invoke(app, ["demo", "--out", str(tmp_path / "out"), "--json"])
    assert result.exit_code == 0, result.output
    assert len(seen) == 1 and seen[0] is not None and folder_lock.holder(tmp_path / "out") is None
