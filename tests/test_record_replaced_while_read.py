"""A record replaced (``run --overwrite``) while ``report`` or ``diagnose`` reads it: the files made from the old
record were written beside the new one (report.html of 40 cycles beside a record of 2, once a baseline.json bound to
the old record that the next ``diagnose`` refused), and both commands ended 0. Each is now written only under the
folder's lock while record.mcap is still the file read (``record.beside``); otherwise nothing is written, one line,
exit 2. The replacing run is a real ``cellguard run --overwrite`` in another process, started at the step named."""

from __future__ import annotations

import importlib
import json
import os
import shutil
import subprocess
import sys
import threading
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.record import folder_lock
from cellguard.record.writer import RECORD_FILE
from cellguard.runtime import run_scenario
from cellguard.scenario import parse_scenario

runner = CliRunner()
CLI = [sys.executable, "-c", "from cellguard.cli import app; app()"]
BESIDE = ("report.html", "baseline.json", "fixes.json")
# holds a folder's lock as a run does, until its stdin closes
HOLDER = ("import sys; from cellguard.record import folder_lock; fd = folder_lock.hold(sys.argv[1]); "
          "print('held', flush=True); sys.stdin.read()")


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """A finished run folder, never diagnosed (nothing beside its record but its summary and index)."""
    out = tmp_path_factory.mktemp("replaced") / "run"
    run_scenario(parse_scenario({"cell": "arm-pick-place", "seed": 5, "acceptance_cycles": 5,
                                 "production_cycles": 1}), out)
    return out


@pytest.fixture
def run(finished, tmp_path) -> Path:
    return Path(shutil.copytree(finished, tmp_path / "d"))


def _tiny(folder: Path) -> Path:
    """A scenario of one acceptance and one production cycle, written in ``folder``."""
    scenario = folder / "tiny.yaml"
    scenario.write_text(yaml.safe_dump({"cell": "arm-pick-place", "seed": 7, "acceptance_cycles": 1,
                                        "production_cycles": 1}))
    return scenario


def _overwrite(folder: Path) -> None:
    """Replace ``folder``'s record with a new run's, as a technician's ``run --overwrite`` does."""
    done = subprocess.run([*CLI, "run", str(_tiny(folder.parent)), "--out", str(folder), "--overwrite"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr


def _replacing_after(monkeypatch, target: str, folder: Path) -> None:
    """The function at ``target`` ("module.name") replaces ``folder``'s record once it has run."""
    module, name = target.rsplit(".", 1)
    module = importlib.import_module(module)
    real = getattr(module, name)

    def then_replaced(*args, **kwargs):
        result = real(*args, **kwargs)
        _overwrite(folder)
        return result

    monkeypatch.setattr(module, name, then_replaced)


def _new_run_only(folder: Path, before: int) -> None:
    """``folder`` holds the replacing run's record and nothing made from the record read before."""
    assert os.stat(folder / RECORD_FILE).st_ino != before
    assert not [name for name in BESIDE if (folder / name).exists()]
    assert not [p.name for p in folder.iterdir() if p.name.startswith(".")]  # no temporary file left


def _replaced_during(monkeypatch, run: Path, step: str, command: str, doing: str, page: str) -> None:
    """``command`` on ``run``, whose record is replaced once ``step`` has run: one line, exit 2, nothing of the old
    record's beside the new one."""
    before = os.stat(run / RECORD_FILE).st_ino
    _replacing_after(monkeypatch, step, run)
    result = runner.invoke(app, [command, str(run), "--no-fleet"])
    assert result.exit_code == 2, result.output
    assert result.stderr == f"error: {run}: its record was replaced while it was being {doing}; {page} not written\n"
    assert result.stdout == ""
    _new_run_only(run, before)


def test_report_of_a_record_replaced_before_its_page_is_written_writes_no_page(run, monkeypatch):
    # the baseline and fixes written before the replacement went with the old record
    _replaced_during(monkeypatch, run, "cellguard.report.from_record.render_report", "report", "reported", "report.html")


def test_diagnosis_of_a_record_replaced_before_its_baseline_is_written_writes_nothing(run, monkeypatch):
    _replaced_during(monkeypatch, run, "cellguard.diagnose.from_record.diagnose", "diagnose", "diagnosed",
                     "baseline.json")
    again = runner.invoke(app, ["diagnose", str(run), "--no-fleet"])  # the new record's own: no stale baseline refused
    assert "bound to record_id" not in again.stderr and "needs at least 5 acceptance cycles" in again.stderr


def test_report_that_reads_the_replacing_record_says_it_was_replaced(run, monkeypatch):
    """Replaced between the report's first read and the diagnosis: the diagnosis read the new, 1-cycle record and
    said 'needs at least 5 acceptance cycles, got 1' of a record that has 5."""
    _replacing_after(monkeypatch, "cellguard.cli.diagnose.record_health", run)
    result = runner.invoke(app, ["report", str(run), "--no-fleet"])
    assert result.exit_code == 2, result.output
    assert result.stderr == f"error: {run}: its record was replaced while it was being reported; nothing written\n"
    assert not [name for name in BESIDE if (run / name).exists()]


def test_a_page_is_not_written_while_a_run_holds_the_folder(run, monkeypatch):
    """A run that has taken the folder (and is about to replace its record) when the page is to be written."""
    monkeypatch.setattr(folder_lock, "BRIEF_S", 0.2, raising=False)
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(run)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              text=True)
    try:
        assert holder.stdout.readline() == "held\n"
        result = runner.invoke(app, ["report", str(run), "--no-fleet"])
    finally:
        holder.communicate("")
    assert result.exit_code == 2, result.output
    assert result.stderr == (f"error: {run}: another process is writing there now (pid {holder.pid}); report.html "
                             "not written: run it again once it has ended\n")
    assert not [name for name in BESIDE if (run / name).exists()]


def test_a_diagnosis_stands_while_another_process_holds_the_folder(run, monkeypatch):
    """The record is the one read: the diagnosis is printed and the files not kept are named (exit 1). It ended in
    exit 2 with no diagnosis, and a fleet push stopped at the first such run folder, pushing nothing."""
    monkeypatch.setattr(folder_lock, "BRIEF_S", 0.2, raising=False)
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(run)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              text=True)
    try:
        assert holder.stdout.readline() == "held\n"
        result = runner.invoke(app, ["diagnose", str(run), "--no-fleet", "--json"])
    finally:
        holder.communicate("")
    assert result.exit_code == 1, result.output
    assert json.loads(result.stdout)["cycles"]
    assert f"another process is writing there now (pid {holder.pid}); baseline.json not written" in result.stderr
    assert not [name for name in BESIDE if (run / name).exists()]


def test_a_fleet_signature_of_a_record_replaced_while_diagnosed_is_left_out_by_name(run, monkeypatch):
    from cellguard.fleet.from_record import site_signatures
    from cellguard.fleet.policy import DataPolicy

    _replacing_after(monkeypatch, "cellguard.diagnose.from_record.diagnose", run)
    skipped: list[str] = []
    assert site_signatures(run.parent, DataPolicy("ta", "s1"), skipped=skipped) == []
    assert skipped == [f"{run}: its record was replaced while it was being diagnosed; baseline.json not written; its "
                       "findings were left out"]


def test_a_report_elsewhere_of_a_record_replaced_while_read_is_not_written(run, monkeypatch, tmp_path):
    """-o FILE outside the run folder: the page's text came from the old record and its charts from the new one
    (a mixed page, exit 0)."""
    _replacing_after(monkeypatch, "cellguard.report.from_record.render_report", run)
    result = runner.invoke(app, ["report", str(run), "--no-fleet", "-o", str(tmp_path / "page.html")])
    assert result.exit_code == 2, result.output
    assert "its record was replaced while it was being reported; page.html not written" in result.stderr
    assert not (tmp_path / "page.html").exists()


def test_a_fifo_given_as_the_record_is_never_opened(tmp_path):
    """Opening a FIFO releases a writer blocked on it (scan's rule: neither a FIFO nor a device is opened)."""
    (tmp_path / "d").mkdir()
    fifo = tmp_path / "d" / RECORD_FILE
    os.mkfifo(fifo)
    writer = threading.Thread(target=lambda: open(fifo, "wb").close(), daemon=True)
    writer.start()
    try:
        assert runner.invoke(app, ["diagnose", str(tmp_path / "d"), "--no-fleet"]).exit_code == 2
        writer.join(0.5)
        assert writer.is_alive()  # still waiting for a reader
    finally:
        os.close(os.open(fifo, os.O_RDONLY | os.O_NONBLOCK))  # lets it go
        writer.join(5)


def test_nothing_replaced_report_and_diagnose_write_as_before(run):
    report = runner.invoke(app, ["report", str(run), "--no-fleet"])
    assert report.exit_code == 0, report.output
    assert all((run / name).is_file() for name in BESIDE)
    assert runner.invoke(app, ["diagnose", str(run), "--no-fleet"]).exit_code == 0


def test_a_report_beside_a_record_it_does_not_pin_is_written(run, tmp_path):
    """-o FILE outside the run folder: nothing of the folder's is written there, no lock is taken."""
    lock = subprocess.Popen([sys.executable, "-c", HOLDER, str(tmp_path)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    try:
        assert lock.stdout.readline() == "held\n"
        result = runner.invoke(app, ["report", str(run), "--no-fleet", "-o", str(tmp_path / "page.html")])
    finally:
        lock.communicate("")
    assert result.exit_code == 0, result.output
    assert (tmp_path / "page.html").is_file()


def test_a_run_start_waits_out_a_readers_short_hold(tmp_path):
    """A reader's write beside a record holds the folder a moment: a run starting then (``hold`` as the recording
    and the demo call it) waits for it, where it was refused as if another run were writing there."""
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(tmp_path)], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True)
    assert holder.stdout.readline() == "held\n"
    let_go = threading.Timer(0.2, holder.stdin.close)
    let_go.start()
    try:
        lock = folder_lock.hold(tmp_path)
    finally:
        let_go.join()
        holder.wait(timeout=60)
    folder_lock.release(lock)


def test_the_refusal_of_a_folder_a_run_holds_names_its_process(tmp_path):
    out = tmp_path / "lk"
    out.mkdir()
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(out)], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline() == "held\n"
        result = runner.invoke(app, ["run", str(_tiny(tmp_path)), "--out", str(out), "--overwrite"])
    finally:
        holder.communicate("")
    assert result.exit_code == 2, result.output
    assert result.stderr == (f"error: --out {out}: another run is still writing its record there (pid "
                             f"{holder.pid}); nothing was touched: wait for it to end or choose another folder\n")


def test_replay_of_a_record_replaced_before_its_page_is_written_writes_no_page(run, monkeypatch):
    """A replay page, replay-cycle-N.html in the run folder, is made from the record as a report is."""
    before = os.stat(run / RECORD_FILE).st_ino
    _replacing_after(monkeypatch, "cellguard.calibrate.replay.replay", run)
    result = runner.invoke(app, ["replay", str(run), "--cycle", "1"])
    assert result.exit_code == 2, result.output
    assert result.stderr == (f"error: {run}: its record was replaced while it was being replayed; "
                             "replay-cycle-1.html not written\n")
    assert os.stat(run / RECORD_FILE).st_ino != before and not (run / "replay-cycle-1.html").exists()


def test_overwrite_removes_the_old_records_replay_pages_and_keeps_other_files(run):
    """A replacing run left the old record's replay pages beside its own record: cycle 1's page read as the new
    record's cycle 1."""
    assert runner.invoke(app, ["replay", str(run), "--cycle", "1"]).exit_code == 0
    (run / "replay-cycle-notes.html").write_text("a technician's own page")
    _overwrite(run)
    assert not (run / "replay-cycle-1.html").exists()
    assert (run / "replay-cycle-notes.html").read_text() == "a technician's own page"
