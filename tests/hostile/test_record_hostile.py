"""Hostile and careless use of the record (issue 14, classes 2 to 4), through the real command line.

Each case runs ``cellguard`` in its own process and asserts the exit code, exactly one error line
on stderr, no traceback, and that files written earlier are byte-identical afterwards.

* class 2: a full disk at the start and in the middle of a run (a real tmpfs of a few MiB, so
  the test mounts one: it needs root and skips otherwise);
* class 3: a run, a recovery or an export never overwrites a record; the index folder is never
  deleted wholesale;
* class 4: a record whose first chunk (the context) is damaged is still read, diagnosed and
  reported, and every reader says what was lost (exit 1); an unreadable file is exit 2.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from run_copies import small_tmpfs

from cellguard.record.reader import open_record
from cellguard.record.scan import scan
from cellguard.record.session import RunRecording
from cellguard.record.writer import RecordConfig
from cellguard.runtime import Run, run_scenario
from cellguard.scenario import parse_scenario

SCENARIO = "cell: arm-pick-place\nseed: 7\nacceptance_cycles: {a}\nproduction_cycles: {p}\n"


def cellguard(*args) -> subprocess.CompletedProcess:
    """The command line in a process of its own, as a user runs it."""
    return subprocess.run([sys.executable, "-c", "from cellguard.cli import app; app()", *map(str, args)],
                          capture_output=True, text=True, timeout=600)


def one_error_line(result: subprocess.CompletedProcess) -> str:
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert "Traceback" not in result.stderr and "Traceback" not in result.stdout
    assert len(lines) == 1, result.stderr
    return lines[0]


def digests(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def scenario_file(tmp_path: Path, acceptance: int, production: int) -> Path:
    path = tmp_path / f"s{acceptance}_{production}.yaml"
    path.write_text(SCENARIO.format(a=acceptance, p=production))
    return path


# -- class 2: a full disk ---------------------------------------------------------------------------
@pytest.fixture
def small_disk(tmp_path):
    """A 4 MiB tmpfs mounted for the test."""
    with small_tmpfs(tmp_path / "disk", "4m") as mount:
        yield mount


def fill(disk: Path, leave: int) -> Path:
    """Write a file of random bytes until only ``leave`` bytes are free on ``disk``."""
    filler = disk / "earlier.bin"
    with open(filler, "wb") as f:
        while True:
            st = os.statvfs(disk)
            room = st.f_bavail * st.f_frsize - leave
            if room <= 0:
                break
            try:
                f.write(os.urandom(min(room, 1 << 16)))
                f.flush()
            except OSError:
                break
    return filler


def test_full_disk_at_start_is_one_line_and_exit_2(small_disk, tmp_path):
    fill(small_disk, 0)
    before = digests(small_disk)
    result = cellguard("run", scenario_file(tmp_path, 1, 0), "--out", small_disk / "run", "--json")
    assert result.returncode == 2
    assert "cannot start the record" in one_error_line(result)
    assert not (small_disk / "run" / "record.mcap").exists()  # no empty record left behind
    after = digests(small_disk)
    assert {k: v for k, v in after.items() if k in before} == before


def test_full_disk_mid_run_stops_the_cell_with_record_failed_and_a_summary(small_disk, tmp_path):
    cycles = 8
    reserve = 256 * 1024 + 8 * 1024 * cycles  # what RunRecording sets aside for summary.json
    filler = fill(small_disk, reserve + 200 * 1024)
    before = digests(small_disk)
    result = cellguard("run", scenario_file(tmp_path, cycles, 0), "--out", small_disk / "run", "--json")
    assert result.returncode == 1
    line = one_error_line(result)
    assert "record_failed" in line and "ENOSPC" in line
    summary = json.loads((small_disk / "run" / "summary.json").read_text())
    assert "ENOSPC" in summary["stopped"]
    stops = [e for e in summary["events"] if e["kind"] == "record_failed"]
    assert len(stops) == 1 and stops[0]["category"] == 2
    assert len(summary["cycles"]) < cycles
    assert digests(small_disk)[filler.name] == before[filler.name]
    info = cellguard("record", "info", small_disk / "run")  # what was written reads back, and says it is cut
    assert info.returncode == 1 and "truncated" in one_error_line(info)


# -- class 3: nothing recorded is overwritten ------------------------------------------------------
@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    out = tmp_path_factory.mktemp("recorded") / "run"
    run_scenario(parse_scenario({"cell": "arm-pick-place", "seed": 7, "acceptance_cycles": 1,
                                 "production_cycles": 0}), out)
    (out / "index" / "notes.txt").write_text("a technician's notes, not cellguard's\n")
    return out


def test_run_onto_a_run_folder_is_refused(recorded, tmp_path):
    before = digests(recorded)
    result = cellguard("run", scenario_file(tmp_path, 1, 0), "--out", recorded)
    assert result.returncode == 2
    assert "choose another --out folder" in one_error_line(result)
    assert digests(recorded) == before


def test_overwrite_replaces_the_record_but_not_unrelated_files(recorded, tmp_path):
    copy = tmp_path / "copy"
    subprocess.run(["cp", "-a", str(recorded), str(copy)], check=True)
    with open_record(copy) as rec:
        old_id = rec.record_id
    result = cellguard("run", scenario_file(tmp_path, 1, 0), "--out", copy, "--overwrite", "--json")
    assert result.returncode == 0, result.stderr
    assert (copy / "index" / "notes.txt").read_text() == "a technician's notes, not cellguard's\n"
    with open_record(copy) as rec:
        assert rec.record_id != old_id and rec.health().ok
    assert len(list((copy / "index" / "cycles").glob("day=*/*.parquet"))) == 1  # the old parts are gone


@pytest.mark.parametrize("target", ["record.mcap", "copy.mcap"])
def test_export_onto_a_record_is_refused(recorded, tmp_path, target):
    if target == "copy.mcap":
        (recorded.parent / target).write_bytes((recorded / "record.mcap").read_bytes())
    before = digests(recorded.parent)
    result = cellguard("record", "export", recorded, "-o", recorded.parent / target if target != "record.mcap"
                       else recorded / target)
    assert result.returncode == 2
    assert "never overwrites a record" in one_error_line(result)
    assert digests(recorded.parent) == before


def test_recover_onto_a_record_is_refused(recorded, tmp_path):
    before = digests(recorded)
    other = tmp_path / "other"
    other.mkdir()
    (other / "record.mcap").write_bytes((recorded / "record.mcap").read_bytes())
    result = cellguard("record", "recover", recorded, "-o", other)
    assert result.returncode == 2
    assert "never overwrites" in one_error_line(result)
    assert digests(recorded) == before
    assert (other / "record.mcap").read_bytes() == (recorded / "record.mcap").read_bytes()


# -- class 4: a damaged context chunk -----------------------------------------------------------------
@pytest.fixture(scope="module")
def damaged(tmp_path_factory):
    """Six cycles with the context repeated every 5 s; then the chunks holding the start's context are damaged."""
    out = tmp_path_factory.mktemp("damaged")
    run = Run(parse_scenario({"cell": "arm-pick-place", "seed": 7, "acceptance_cycles": 5, "production_cycles": 1}))
    run.recording = RunRecording.start(out, run, config=RecordConfig(context_every_s=5.0))
    for _ in range(6):
        run.cycle()
    run.recording.close()
    layout = scan(out / "record.mcap")
    context = next(i for i, c in layout.channels.items() if c.topic == "/context")
    start = layout.chunks[0].start_ns
    with open(out / "record.mcap", "r+b") as f:
        for chunk in layout.chunks:  # the context at start, and again as cycle 0 begins: not the 5 s repeats
            if context in chunk.channels and chunk.start_ns - start < 1_000_000_000:
                f.seek(chunk.offset + chunk.length // 2)
                f.write(b"\xff" * 16)
    return out


@pytest.mark.parametrize("command", [["record", "info"], ["diagnose"], ["report"]])
def test_every_reader_says_the_context_was_lost_and_exits_1(damaged, command):
    record = (damaged / "record.mcap").read_bytes()
    result = cellguard(*command, damaged)
    assert result.returncode == 1
    line = one_error_line(result)
    assert "damaged" in line and "context" in line and "repeat" in line
    assert (damaged / "record.mcap").read_bytes() == record


def test_diagnosis_of_the_damaged_record_still_reads_every_cycle(damaged):
    result = cellguard("diagnose", damaged, "--json")
    assert result.returncode == 1
    doc = json.loads(result.stdout)
    assert doc["cycles"] == 6 and not doc["record"]["ok"]


def test_a_recovered_copy_keeps_the_context_and_says_so(damaged, tmp_path):
    assert cellguard("record", "recover", damaged, "-o", tmp_path / "rec").returncode == 0
    with open_record(tmp_path / "rec") as rec:
        assert rec.context["embodiment"]["robot"] == "arm-pick-place" and rec.context_loss
        assert rec.attachment("robot_description.urdf").startswith(b"<?xml")
        assert len(list(rec.cycles())) == 6


def test_nothing_readable_is_exit_2(tmp_path):
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"[" * 500)
    result = cellguard("record", "info", junk)
    assert result.returncode == 2
    assert "nothing can be recovered" in one_error_line(result)
    assert junk.read_bytes() == b"[" * 500


# -- class 5: a valid MCAP whose JSON messages are off their schema -------------------------------------
def test_off_schema_json_messages_are_skipped_and_reported_as_damage(tmp_path):
    from record_synth import DT_NS, JOINTS, context, tick

    from cellguard.control.events import Event
    from cellguard.record.schemas import BY_TOPIC
    from cellguard.record.writer import Recorder

    folder = tmp_path / "run"
    rec = Recorder.create(folder, joints=JOINTS, dt_ns=DT_NS, context=context(), config=RecordConfig(),
                          epoch_wall_ns=1_790_000_000_000_000_000)
    rec.cycle_begin(0, "acceptance", 0)
    for k in range(100):
        tick(rec, k, 0)
    rec.event(Event(50 * DT_NS, "protective_stop", "test", category=2), 0)
    rec._json(BY_TOPIC["/cycles"].id, 60 * DT_NS, {"marker": "end", "phase": 3})  # no cycle, no times
    rec._json(BY_TOPIC["/events"].id, 61 * DT_NS, {"kind": ["not", "text"]})
    rec.cycle_end({"cycle": 0, "phase": "acceptance", "success": True, "features": {}}, 100 * DT_NS)
    rec.close()
    before = digests(folder)
    with open_record(folder) as r:
        assert [c.cycle for c in r.cycles()] == [0] and [e.kind for e in r.events()] == ["protective_stop"]
        damage = r.health().damage
    assert any("/cycles message(s) off their schema" in d for d in damage)
    assert any("/events message(s) off their schema" in d for d in damage)
    result = cellguard("record", "info", folder)
    assert result.returncode == 1 and "damaged" in one_error_line(result)
    assert digests(folder) == before
