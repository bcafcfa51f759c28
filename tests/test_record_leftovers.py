"""Record leftovers: a cut record opened without decompressing each chunk, an infinite date as a map key in
``record query``, failed recoveries at WARN in the log panel, and events after a cycle's end in no cycle."""

from __future__ import annotations

import datetime as dt
import json
import struct
from pathlib import Path

import duckdb
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from cellguard.control.events import Event, EventKind
from cellguard.record import scan as scan_module
from cellguard.record import query
from cellguard.record.reader import open_record
from cellguard.record.ros2 import DEBUG, INFO, WARN
from cellguard.record.scan import read_chunk, scan
from cellguard.record.writer import RecordConfig, Recorder
from cellguard.robot.state import State
from record_synth import away_from_home_run

JOINTS = ("a", "b")
MS = 1_000_000


def _write(folder: Path, events=(), cycles=((0, 0, 900),)) -> Path:
    """A record of 1,000 ticks at 1 kHz in chunks of 20 ms; ``cycles``: (cycle, begin ms, end ms); ``events``:
    (Event, stamped cycle), written after the ticks up to their time."""
    rec = Recorder.create(folder, joints=JOINTS, dt_ns=MS, context={"site": "s", "cell_id": "c"},
                          config=RecordConfig(chunk_ns=20 * MS, fsync_ns=20 * MS, pre_trigger_s=0.0,
                                              post_trigger_s=0.0))
    z = np.zeros(2)
    todo = sorted([(b * MS, 0, ("begin", c)) for c, b, _ in cycles] + [(e * MS, 1, ("end", c)) for c, _, e in cycles]
                  + [(event.t_ns, 2, ("event", event, cycle)) for event, cycle in events], key=lambda x: x[:2])
    stamp = 0
    for k in range(1000):
        while todo and todo[0][0] <= k * MS:
            _, _, what = todo.pop(0)
            if what[0] == "begin":
                stamp = what[1]
                rec.cycle_begin(what[1], "acceptance", k * MS)
            elif what[0] == "end":
                rec.cycle_end({"cycle": what[1], "phase": "acceptance", "success": True}, k * MS)
            else:
                rec.event(what[1], what[2])
        rec.tick(stamp, z, z, State(k * MS, z + k, z, z, z))
    rec.close()
    return folder / "record.mcap"


def _cut(file: Path, out: Path) -> Path:
    """``file`` cut after its last chunk's message indexes, inside the summary: where a crash leaves a record."""
    layout = scan(file)
    data = file.read_bytes()
    end = layout.chunks[-1].offset + layout.chunks[-1].length
    while data[end] == 0x07:  # the last chunk's message indexes
        end += 9 + int.from_bytes(data[end + 1:end + 9], "little")
    out.mkdir()
    (out / "record.mcap").write_bytes(data[:end + 3])
    return out / "record.mcap"


# 1. a cut record opens without decompressing every chunk


def test_a_cut_record_is_laid_out_from_its_message_indexes_not_by_decompressing_each_chunk(tmp_path, monkeypatch):
    whole = _write(tmp_path / "whole")
    cut = _cut(whole, tmp_path / "cut")
    reads = []
    monkeypatch.setattr(scan_module, "read_chunk", lambda *a, **k: reads.append(a[1]) or read_chunk(*a, **k))
    layout = scan(cut)
    assert layout.truncated and len(layout.chunks) > 40
    # the first chunk, which declares the channels, and the last, cut right after its indexes; before: every chunk
    assert {ref.offset for ref in reads} <= {layout.chunks[0].offset, layout.chunks[-1].offset}
    monkeypatch.undo()
    with open(cut, "rb") as f:
        buf = f.read()
    for ref in layout.chunks:  # each as its records say: what the scan found by decompressing it before
        messages = [r for r in read_chunk(buf, ref) if hasattr(r, "log_time")]
        assert ref.channels == {m.channel_id for m in messages}
        assert (ref.start_ns, ref.end_ns) == (min(m.log_time for m in messages), max(m.log_time for m in messages))
    with open_record(whole.parent) as full, open_record(cut.parent) as rec:
        window = dict(start_ns=400 * MS, end_ns=500 * MS)
        assert np.array_equal(rec.ticks(**window).q_meas, full.ticks(**window).q_meas)
        assert rec.health().chunks_ok == len(layout.chunks) and not rec.health().damage


def test_a_damaged_chunk_of_a_cut_record_is_still_found_and_skipped(tmp_path):
    """A chunk no longer decompressed by the scan is checked against its CRC when it is read: damage all the same."""
    cut = _cut(_write(tmp_path / "whole"), tmp_path / "cut")
    layout = scan(cut)
    ref = layout.chunks[len(layout.chunks) // 2]
    data = bytearray(cut.read_bytes())
    data[ref.offset + ref.length - 20] ^= 0xFF  # inside its compressed records
    cut.write_bytes(bytes(data))
    with open_record(cut.parent) as rec:
        health = rec.health()
        ticks = rec.ticks(rate="decimated")
    assert health.chunks_damaged == 1 and any(f"chunk at byte {ref.offset}" in d for d in health.damage)
    assert 0 < len(ticks) and not health.ok


@pytest.mark.parametrize("into", [0, 7, 14])
def test_a_record_cut_inside_a_chunks_message_indexes_reads_every_message_of_that_chunk(tmp_path, into):
    """Cut between two of the last chunk's indexes (or 7, 14 bytes into the next), it was laid out from the indexes
    read so far: the unindexed topics' messages of that chunk were skipped, with no damage said. It is decompressed."""
    whole = _write(tmp_path / "whole")
    data, last = whole.read_bytes(), scan(whole).chunks[-1]
    at = last.offset + last.length
    at += 9 + int.from_bytes(data[at + 1:at + 9], "little")  # past its first index
    (tmp_path / "cut").mkdir()
    cut = tmp_path / "cut" / "record.mcap"
    cut.write_bytes(data[:at + into])
    with open_record(whole.parent) as full, open_record(cut.parent) as rec:
        assert rec.layout.chunks[-1].offset == last.offset
        assert rec.layout.chunks[-1].channels == full.layout.chunks[-1].channels
        assert len(rec.ticks()) == len(full.ticks())


def test_an_index_whose_times_lie_outside_its_chunks_own_is_not_trusted(tmp_path):
    """A flipped bit in an index's log time moved a chunk out of a window read: one tick missing, no damage said."""
    cut = _cut(_write(tmp_path / "whole"), tmp_path / "cut")
    layout, data = scan(cut), bytearray(cut.read_bytes())
    ref = layout.chunks[len(layout.chunks) // 2]
    index = ref.offset + ref.length
    data[index + 15 + 7] ^= 0x40  # the top byte of its first entry's log time
    cut.write_bytes(bytes(data))
    assert (scan(cut).chunks[len(layout.chunks) // 2].start_ns, scan(cut).chunks[len(layout.chunks) // 2].end_ns) == (
        ref.start_ns, ref.end_ns)


def test_a_foreign_files_channels_declared_in_a_chunk_with_none_of_their_messages_are_found(tmp_path):
    """mcap's own Writer declares a channel in the chunk where it is registered, which may hold no message of it (so
    no index says so): that chunk laid out from its indexes lost the channel, and its topic with it."""
    from mcap.writer import CompressionType, Writer

    with open(tmp_path / "x.mcap", "wb") as f:
        w = Writer(f, chunk_size=2000, compression=CompressionType.ZSTD)
        w.start("x", "another tool")
        a = w.register_channel("/a", "json", w.register_schema("A", "jsonschema", b"{}"))
        for i in range(50):
            w.add_message(a, i, b'{"v": 1}' * 10, i)
        b = w.register_channel("/b", "json", w.register_schema("B", "jsonschema", b"{}"))
        for i in range(50, 150):
            w.add_message(a if i < 100 else b, i, b'{"v": 1}' * 10, i)
        w.finish()
    data = (tmp_path / "x.mcap").read_bytes()
    (tmp_path / "x.mcap").write_bytes(data[:data.rfind(bytes([0x0F, 4, 0, 0, 0, 0, 0, 0, 0]))])  # cut at DataEnd
    assert scan(tmp_path / "x.mcap").topics == {1: "/a", 2: "/b"}


# 2. an infinite date as a map key


_ENDS = {dt.date.max: "infinity", dt.date.min: "-infinity", dt.datetime.max: "infinity",
         dt.datetime.min: "-infinity"}
_keys = st.sampled_from(sorted(_ENDS, key=repr)) | st.dates() | st.datetimes()


@settings(max_examples=200, deadline=None)
@given(st.dictionaries(_keys, st.integers(), max_size=6))
def test_an_infinite_date_key_is_named_as_duckdb_writes_it_and_never_a_date(mapping):
    printed = json.loads(query.json_line(["m"], (mapping,)))["m"]
    want = {_ENDS.get(k) or str(k): v for k, v in mapping.items()}
    assert printed == want
    assert not any(k.startswith(("9999-12-31", "0001-01-01")) for k in printed)


def test_duckdb_infinite_date_and_timestamp_keys_print_as_infinity(tmp_path):
    row = duckdb.sql("SELECT MAP {'infinity'::DATE: 1, '-infinity'::DATE: 2, '2024-05-01'::DATE: 3} AS d, "
                     "MAP {'infinity'::TIMESTAMP: 'infinity'::TIMESTAMP} AS t").fetchall()[0]
    assert json.loads(query.json_line(["d", "t"], row)) == {"d": {"infinity": 1, "-infinity": 2, "2024-05-01": 3},
                                                            "t": {"infinity": None}}


# 3. a recovery that did not resume the cell is a warning in the log panel


def _levels(file: Path) -> dict[str, int]:
    """The log level of each /events/log line, by its text (the level byte follows the header and the stamp)."""
    with open(file, "rb") as f:
        out = {}
        for _, channel, message in make_reader(f).iter_messages(topics=["/events/log"]):
            text_at = 4 + 8 + 4  # header, stamp, level padded to the string length's alignment
            name_len = struct.unpack_from("<I", message.data, text_at)[0]
            at = text_at + 4 + name_len
            at += -(at - 4) % 4
            size = struct.unpack_from("<I", message.data, at)[0]
            out[message.data[at + 4:at + 4 + size - 1].decode()] = message.data[12]
    return out


@pytest.mark.parametrize("outcome, level", [("failed", WARN), ("escalated", WARN), ("gave_up", WARN),
                                            ("cut_off", WARN), ("resumed", DEBUG)])
def test_a_recovery_end_is_logged_at_warn_unless_it_resumed(tmp_path, outcome, level):
    attempt = {"behaviour": "retry_grasp", "trigger": "grasp_missed", "attempt": 1, "outcome": outcome,
               "duration_s": 0.5}
    events = [(Event(300 * MS, EventKind.RECOVERY_START, "retry_grasp: attempt 1"), 0),
              (Event(400 * MS, EventKind.RECOVERY_END, f"retry_grasp: attempt 1; outcome {outcome}",
                     recovery=attempt), 0),
              (Event(450 * MS, EventKind.LIMIT_INTERVENTION, "clamped", joint="a", asked=1.0, sent=0.5), 0)]
    file = _write(tmp_path / "r", events)
    levels = {text.split("]")[0].lstrip("["): value for text, value in _levels(file).items()}
    assert levels == {"recovery_start": DEBUG, "recovery_end": level, "limit_intervention": INFO}
    with open_record(file.parent) as rec:  # read back as before: the level is the log panel's only
        ended = [e for e in rec.events() if e.kind == "recovery_end"]
        assert [(e.cycle, e.recovery) for e in ended] == [(0, attempt)]


# 4. an event after its cycle's end lies in no cycle


def test_an_event_stamped_with_a_cycle_that_ended_before_it_reads_in_no_cycle(tmp_path):
    """As a record written before this fix stamps it: the event after the end carries the ended cycle."""
    events = [(Event(500 * MS, EventKind.LIMIT_INTERVENTION, "in", joint="a", asked=1.0, sent=0.5), 0),
              (Event(950 * MS, EventKind.RETREAT_BEGIN, "after"), 0),
              (Event(5 * MS, EventKind.LIMIT_INTERVENTION, "before", joint="a", asked=1.0, sent=0.5), 0)]
    file = _write(tmp_path / "r", events, cycles=((0, 100, 900),))
    with open_record(file.parent) as rec:
        assert {e.reason: e.cycle for e in rec.events()} == {"in": 0, "after": None, "before": None}


def test_a_runs_retreat_events_after_its_last_cycle_are_recorded_in_no_cycle(tmp_path):
    """The session stamps them so, the first at the last cycle's very end (the time cycle ends mid-motion and the
    retreat brakes from there): the record's events and the index's rows (``record query``) agree."""
    with open_record(away_from_home_run(tmp_path, 2, 0)) as rec:
        last_end = rec.cycle_spans()[1][1]
        after = [e for e in rec.events() if e.t_ns >= last_end]
        assert after[0].t_ns == last_end and all(e.cycle is None for e in after)
        with open(rec.file, "rb") as f:  # as written, not only as read
            written = [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(topics=["/events"])]
    assert all("cycle" not in d for d in written if d["t_ns"] >= last_end)
    names, rows = query.run_query(tmp_path / "run", f"SELECT cycle FROM events WHERE t_ns >= {last_end}")
    assert [r[0] for r in rows] == [None] * len(after)


@pytest.mark.parametrize("reason", ["retry_grasp: attempt 2 cannot be planned", "no recovery left (2 attempts): home, "
                                    "the cycle fails"])
def test_a_recovery_end_with_no_attempt_is_logged_at_warn(tmp_path, reason):
    """An attempt that could not be planned, and no recovery left, end with no attempt's fields: read as resumed,
    they were DEBUG, and a recovery that never ran left no warning in the log panel."""
    file = _write(tmp_path / "r", [(Event(400 * MS, EventKind.RECOVERY_END, reason), 0)])
    assert {text.split("]")[0].lstrip("["): value for text, value in _levels(file).items()} == {"recovery_end": WARN}
