"""Record edges: a run killed between cycles cuts none short, an event after a cycle's end at its very time lies in
no cycle, ``record query`` reads an older record's events as ``events()`` does, and a chunk whose message indexes
leave a channel out is damage, never a silent loss."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.opcode import Opcode
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.control.events import Event, EventKind
from cellguard.record import query
from cellguard.record.reader import open_record
from cellguard.record.recovery import recover
from cellguard.record.scan import scan
from cellguard.record.schemas import CHANNELS
from cellguard.record.writer import RecordConfig, Recorder
from cellguard.robot.state import State

MS = 1_000_000
JOINTS = ("a", "b")
TESTS = Path(__file__).parent


def _recorder(folder: Path) -> Recorder:
    """A record of two joints at 1 kHz, chunks of 20 ms."""
    return Recorder.create(folder, joints=JOINTS, dt_ns=MS, context={"site": "s", "cell_id": "c"},
                           config=RecordConfig(chunk_ns=20 * MS, fsync_ns=20 * MS, pre_trigger_s=0.0,
                                               post_trigger_s=0.0))


def _ticks(rec: Recorder, first: int, last: int, stamp: int) -> None:
    z = np.zeros(len(JOINTS))
    for k in range(first, last + 1):
        rec.tick(stamp, z, z, State(k * MS, z + k, z, z, z))


def _index_events(folder: Path) -> dict[str, int | None]:
    """reason -> cycle of the index's events, as ``record query`` answers."""
    _, rows = query.run_query(folder, "SELECT reason, cycle FROM events")
    return dict(rows)


# 1. killed between cycles


def test_run_lost_is_in_the_cycle_of_the_last_tick_only_if_that_cycle_had_not_ended(tmp_path):
    for name, ended in (("open", False), ("ended", True)):
        rec = _recorder(tmp_path / name)
        rec.cycle_begin(0, "acceptance", 0)
        _ticks(rec, 0, 300, 0)
        if ended:
            rec.cycle_end({"cycle": 0, "phase": "acceptance", "success": True}, 300 * MS)
        rec.run_lost("killed")
        rec.close()
    with open_record(tmp_path / "open") as rec:
        assert [(e.kind, e.cycle, e.t_ns) for e in rec.events()] == [("run_process_lost", 0, 300 * MS)]
    with open_record(tmp_path / "ended") as rec:  # after the end, in no cycle: no reader places it in the cycle
        assert [(e.kind, e.cycle, e.t_ns) for e in rec.events()] == [("run_process_lost", None, 300 * MS + 1)]
    assert _index_events(tmp_path / "ended") == {"killed": None}


def test_a_run_sigkilled_between_cycles_cuts_its_last_cycle_not_short(tmp_path):
    """Killed right after its seventh cycle's end (5 acceptance, 2 production): the writer records the loss, and
    ``diagnose`` reads seven whole cycles, none cut short (it read the last cycle as cut short by the kill)."""
    out = tmp_path / "run"
    script = (f"import os, signal, sys; sys.path.insert(0, {str(TESTS)!r})\n"
              "from test_record_run import _short_demo\n"
              "from cellguard.record.session import RunRecording\n"
              "from cellguard.runtime import Run\n"
              "run = Run(_short_demo(8).model_copy(update={'acceptance_cycles': 5, 'production_cycles': 3}))\n"
              f"run.recording = RunRecording.start({str(out)!r}, run)\n"
              "for _ in range(7):\n"
              "    run.cycle()\n"
              "os.kill(os.getpid(), signal.SIGKILL)\n")
    assert subprocess.run([sys.executable, "-c", script], timeout=300).returncode == -signal.SIGKILL
    deadline = time.monotonic() + 30
    while not _finished(out) and time.monotonic() < deadline:  # the orphaned writer finishes the file
        time.sleep(0.05)
    with open_record(out) as rec:
        last_end = rec.cycle_spans()[6][1]
        lost = [e for e in rec.events() if e.kind == "run_process_lost"]
    assert [(e.cycle, e.t_ns > last_end) for e in lost] == [(None, True)]
    result = CliRunner().invoke(app, ["diagnose", str(out), "--json"])
    assert result.exit_code == 0, result.output
    d = json.loads(result.output)
    assert d["cycles"] == 7
    assert d["run_end"]["kind"] == "run_process_lost" and d["run_end"]["cycle"] is None
    assert d["cut_short_cycles"]["cycles"] == []
    info = CliRunner().invoke(app, ["record", "info", str(out)])
    assert "between cycles, not by the run: the run's process ended" in info.output


def _finished(folder: Path) -> bool:
    if not (folder / "record.mcap").exists():
        return False
    with open_record(folder) as rec:
        return rec.health().finished


# 2. an event at a cycle's end time: in the cycle if raised before its end, else in none


def test_an_event_at_a_cycles_end_time_is_in_it_only_if_raised_before_its_end(tmp_path):
    rec = _recorder(tmp_path / "r")
    rec.cycle_begin(0, "acceptance", 100 * MS)
    _ticks(rec, 0, 900, 0)
    rec.event(Event(900 * MS, EventKind.OPERATOR_STOP, "read on the last tick"), 0)
    rec.cycle_end({"cycle": 0, "phase": "acceptance", "success": False}, 900 * MS)
    rec.event(Event(900 * MS, EventKind.RETREAT_BEGIN, "after the end"), 0)
    _ticks(rec, 901, 950, 0)
    rec.close()
    with open_record(tmp_path / "r") as rec:
        assert {e.reason: e.cycle for e in rec.events()} == {"read on the last tick": 0, "after the end": None}
        log = [m.data for m in rec.messages(["/events/log"])]
    assert _index_events(tmp_path / "r") == {"read on the last tick": 0, "after the end": None}
    assert any(b"[retreat_begin] between cycles" in data for data in log)


# 3. an older record's index: record query re-stamps as events() reads


def test_record_query_reads_an_older_records_events_after_a_cycles_end_in_no_cycle(tmp_path):
    """Written as the recorder before did: every event with the cycle begun last, in the record and in the index's
    events table (``event_row`` with that cycle); given before the end marker, this recorder keeps the stamp too."""
    rec = _recorder(tmp_path / "old")
    rec.cycle_begin(0, "acceptance", 100 * MS)
    _ticks(rec, 0, 900, 0)
    for t_ms, reason in ((50, "before its begin"), (500, "inside"), (900, "at its end"), (950, "after its end")):
        rec.event(Event(t_ms * MS, EventKind.LIMIT_INTERVENTION, reason, joint="a", asked=1.0, sent=0.5), 0)
    rec.cycle_end({"cycle": 0, "phase": "acceptance", "success": True}, 900 * MS)
    _ticks(rec, 901, 999, 0)
    rec.close()
    read = {"before its begin": None, "inside": 0, "at its end": 0, "after its end": None}
    with open_record(tmp_path / "old") as rec:
        assert {e.reason: e.cycle for e in rec.events()} == read
    assert _index_events(tmp_path / "old") == read
    _, rows = query.run_query(tmp_path / "old", "SELECT count(*) FROM events WHERE cycle IS NULL")
    assert list(rows) == [(2,)]


# 4. a chunk whose message indexes leave a channel out


_IDS = {c.topic: c.id for c in CHANNELS}


def _record_without_indexes(folder: Path, drop: dict[int, set[str]]) -> int:
    """Three cycles with an event every 40 ms, in chunks of 20 ms; chunk ``n`` (counted after the start) written
    without the message indexes of the topics ``drop[n]`` names, as an edit that took them out of the file and its
    summary (the mcap Writer leaves them out of the chunk index too). Returns the number of events."""
    rec = _recorder(folder)
    writer, count, flush = rec._writer, [0], rec._writer.flush
    builder = writer._Writer__chunk_builder  # mcap's own: the message index records it writes after the chunk

    def dropping():
        if builder.num_messages:
            for topic in drop.get(count[0], ()):
                builder.message_indices.pop(_IDS[topic], None)
            count[0] += 1
        flush()

    writer.flush = dropping
    z, events = np.zeros(len(JOINTS)), 0
    for c in range(3):
        rec.cycle_begin(c, "acceptance", c * 300 * MS)
        for k in range(c * 300, c * 300 + 300):
            rec.tick(c, z, z, State(k * MS, z + k, z, z, z))
            if k % 40 == 5:
                rec.event(Event(k * MS, EventKind.LIMIT_INTERVENTION, f"e{k}", joint="a", asked=1.0, sent=0.5), c)
                events += 1
        rec.cycle_end({"cycle": c, "phase": "acceptance", "success": True}, (c * 300 + 299) * MS)
    rec.close()
    return events


def _cut(folder: Path) -> None:
    """The record of ``folder`` cut a few bytes after its last chunk's message indexes, as a crash leaves it: read by
    a linear scan."""
    file = folder / "record.mcap"
    last = scan(file).chunks[-1]
    data = file.read_bytes()
    end = last.offset + last.length
    while data[end] == Opcode.MESSAGE_INDEX:  # its message indexes
        end += 9 + int.from_bytes(data[end + 1:end + 9], "little")
    file.write_bytes(data[:end + 3])


@pytest.mark.parametrize("cut", [False, True])
def test_a_chunk_whose_message_index_for_events_was_removed_is_damage_and_its_events_still_read(tmp_path, cut):
    total = _record_without_indexes(tmp_path / "r", {n: {"/events"} for n in range(1, 40, 2)})
    if cut:
        _cut(tmp_path / "r")
    with open_record(tmp_path / "r") as rec:  # events() finds them without health(): diagnose never runs it
        first = [e.reason for e in rec.events()]
        health = rec.health()
        after = [e.reason for e in rec.events()]
    notes = [d for d in health.damage if "message indexes leave out" in d]
    assert notes and all("/events message(s)" in d for d in notes) and not health.ok
    assert first == after and len(after) == total == len(set(after))  # read from the chunks themselves
    copy = tmp_path / "copy"
    recover(tmp_path / "r", copy)
    with open_record(copy) as rec:
        assert len(list(rec.events())) == total and not [d for d in rec.health().damage if "leave out" in d]


def test_a_file_written_without_message_indexes_reads_whole(tmp_path):
    """An empty map of message index offsets says the file has no message indexes (MCAP spec), not that the chunk
    holds no channel: every message was skipped."""
    total = _record_without_indexes(tmp_path / "r", {n: set(_IDS) for n in range(200)})
    with open_record(tmp_path / "r") as rec:
        assert len(list(rec.events())) == total and len(list(rec.cycles())) == 3
        assert len(rec.ticks(rate="decimated")) > 0 and rec.health().ok


def _contents(rec) -> tuple:
    """What the readers give: events, cycles, decimated tick times, joint states."""
    return ([e.reason for e in rec.events()], [c.cycle for c in rec.cycles()],
            rec.ticks(rate="decimated").t_ns.tolist(), len(list(rec.messages(["/joint_states"]))))


@settings(max_examples=12, deadline=None)
@given(st.dictionaries(st.integers(0, 45), st.sets(st.sampled_from(["/events", "/cycles", "/ticks/decimated",
                                                                      "/joint_states"]), min_size=1), max_size=6),
       st.booleans())
def test_no_removed_message_index_loses_messages_silently(drop, cut):
    """Whatever indexes are removed, from a finished or a cut file: a read that misses messages comes with a damage
    note naming a removed topic, and after ``health`` every message reads as in the untouched record."""
    with tempfile.TemporaryDirectory() as tmp:
        whole, edited = Path(tmp) / "whole", Path(tmp) / "edited"
        _record_without_indexes(whole, {})
        _record_without_indexes(edited, drop)
        if cut:
            _cut(whole)
            _cut(edited)
        with open_record(whole) as a, open_record(edited) as b:
            want, before = _contents(a), _contents(b)
            health = b.health()
            assert _contents(b) == want
    notes = [d for d in health.damage if "leave out" in d]
    named = {topic for d in notes for topic in _IDS if f" {topic} message" in d}
    assert named <= set().union(*drop.values())
    assert before == want or named
    assert cut or health.ok == (not notes)


# 5. review of aac5016: left-out events read by every reader, an index part of another run, a cycle begun again,
# a lost run in a cycle the record never marks, a summary without chunk indexes


def test_diagnose_reads_the_events_a_chunks_message_indexes_leave_out(tmp_path):
    """``diagnose`` reads events in an ``open_record`` of its own, without ``health``: it read none of them."""
    from record_synth import record
    from test_record_health_chunk_index import _leave_out

    ticks = (130, 330, 530, 730)
    record(tmp_path / "r", cycles=10, ticks_per_cycle=100, events=dict.fromkeys(ticks, "limit_intervention"))
    path = tmp_path / "r" / "record.mcap"
    with open_record(path) as rec:
        channel = rec.channel_id("/events")
    for ref in scan(path).chunks:
        if channel in ref.channels:
            _leave_out(path, channel, ref.offset)
    assert not any(channel in ref.channels for ref in scan(path).chunks)
    result = CliRunner().invoke(app, ["diagnose", str(tmp_path / "r"), "--json"])
    assert len(json.loads(result.stdout)["safety_events"]) == len(ticks), result.output


def test_record_query_places_events_by_this_records_index_parts_only(tmp_path):
    """A part naming no record id (an older run's, left by a killed ``--overwrite``) is not this record's:
    ``events()`` takes no span from it, nor does ``record query``."""
    import pyarrow.parquet as pq

    for name, start in (("run", 0), ("other", 200)):
        rec = _recorder(tmp_path / name)
        rec.cycle_begin(0, "acceptance", start * MS)
        _ticks(rec, 0, 400, 0)
        rec.event(Event((start + 50) * MS, EventKind.LIMIT_INTERVENTION, name, joint="a", asked=1.0, sent=0.5), 0)
        rec.cycle_end({"cycle": 0, "phase": "acceptance", "success": True}, (start + 100) * MS)
        rec.close()
    for part in (tmp_path / "other/index/cycles").glob("day=*/*.parquet"):
        left = tmp_path / "run/index/cycles" / part.parent.name / "part-99999999.parquet"
        left.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(pq.read_table(part).replace_schema_metadata(None), left)
    with open_record(tmp_path / "run") as rec:
        assert {e.reason: e.cycle for e in rec.events()} == {"run": 0}
    assert _index_events(tmp_path / "run") == {"run": 0}


def test_a_cycle_number_begun_again_holds_its_events(tmp_path):
    rec = _recorder(tmp_path / "r")
    for n, start in enumerate((0, 200)):
        rec.cycle_begin(0, "acceptance", start * MS)
        _ticks(rec, start, start + 100, 0)
        rec.event(Event((start + 50) * MS, EventKind.LIMIT_INTERVENTION, f"run {n}", joint="a", asked=1.0, sent=0.5), 0)
        rec.cycle_end({"cycle": 0, "phase": "acceptance", "success": True}, (start + 100) * MS)
    rec.close()
    with open_record(tmp_path / "r") as rec:
        assert {e.reason: e.cycle for e in rec.events()} == {"run 0": None, "run 1": 0}  # the span is the last's
    assert _index_events(tmp_path / "r") == {"run 0": None, "run 1": 0}
    with open_record(tmp_path / "r") as rec:  # the record's own stamp, before any span is applied
        stamps = {json.loads(m.data)["reason"]: json.loads(m.data).get("cycle") for m in rec.messages(["/events"])}
    assert stamps == {"run 0": 0, "run 1": 0}


@pytest.mark.parametrize("begun", [False, True])
def test_a_lost_run_is_placed_only_in_a_cycle_the_record_marks(tmp_path, begun):
    """Killed on the next cycle's first tick, its begin still queued in the dead process (``begun``), or ticking
    with no cycle begun: ``record info`` named a cycle the record never marks."""
    rec = _recorder(tmp_path / "r")
    if begun:
        rec.cycle_begin(0, "acceptance", 0)
        _ticks(rec, 0, 100, 0)
        rec.cycle_end({"cycle": 0, "phase": "acceptance", "success": True}, 100 * MS)
    _ticks(rec, 101, 101, 1 if begun else 0)  # stamped with a cycle whose begin the writer never got
    rec.run_lost("killed")
    rec.close()
    with open_record(tmp_path / "r") as rec:
        assert [(e.cycle, e.t_ns) for e in rec.events()] == [(None, 101 * MS)]
    info = " ".join(CliRunner().invoke(app, ["record", "info", str(tmp_path / "r")]).output.split())
    assert f"ended t=0.101 s{' between cycles' if begun else ''}, not by the run: killed" in info


def test_a_summary_without_chunk_indexes_reads_by_a_scan(tmp_path, monkeypatch):
    """Chunk indexes are optional (MCAP spec): mcap's Writer leaves them out with IndexType.NONE; nothing was read."""
    import functools

    import record_synth
    from mcap.writer import IndexType, Writer

    record_synth.record(tmp_path / "source", cycles=4, ticks_per_cycle=100, events={150: "limit_intervention"})
    monkeypatch.setattr(record_synth, "Writer", functools.partial(Writer, index_types=IndexType.NONE))
    record_synth.rewrite(tmp_path / "source", tmp_path / "copy", chunk_size=16 << 10)
    with open_record(tmp_path / "source") as a, open_record(tmp_path / "copy") as b:
        assert b.layout.finished and len(b.layout.chunks) > 1
        assert list(b.events()) == list(a.events()) and list(b.cycles()) == list(a.cycles())
        assert b.health().ok
