"""A crafted summary whose chunk index leaves a channel out: every read by the indexes (cellguard's, the mcap
package's) skips that channel's messages in the chunk. ``health()`` says so as damage and checks them (c526a15 checked
only the listed channels, so the loss went unsaid), and the readers read them too."""

from __future__ import annotations

import json
import struct
import zlib
from io import BytesIO
from pathlib import Path

from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import ChunkIndex, Message
from record_synth import DT_NS, record, rewrite

from cellguard.record.reader import open_record
from cellguard.record.scan import MAGIC, ChunkRef, open_buffer, read_chunk, scan

EVENT_TICKS = (100, 300, 500, 700, 900, 1100)  # one event 200 ms apart: each in a chunk of its own
BAD_TICK = 500  # the event made malformed
_FOOTER = struct.Struct("<BQQQI")  # opcode, length, summary start, summary offset start, summary CRC


def _malformed(topic: str, d: dict) -> dict:
    """The event at ``BAD_TICK`` with text where a number belongs: a reader skips it as malformed."""
    return {**d, "asked": "text"} if topic == "/events" and d["t_ns"] == BAD_TICK * DT_NS else d


def _chunk_holding_bad_event(path: Path, channel: int) -> int:
    """The offset of the chunk holding the malformed event."""
    layout = scan(path)
    with open_buffer(path) as buf:
        for ref in layout.chunks:
            for m in read_chunk(buf, ChunkRef(ref.offset, ref.length, ref.start_ns, ref.end_ns)):
                if isinstance(m, Message) and m.channel_id == channel and json.loads(m.data)["asked"] == "text":
                    return ref.offset
    raise AssertionError("no chunk holds the malformed event")


def _leave_out(path: Path, channel: int, chunk_offset: int) -> None:
    """Re-emit the summary of ``path`` with the chunk index of the chunk at ``chunk_offset`` not listing ``channel``
    (the MCAP spec: a chunk index's message_index_offsets name the channels in its chunk); the summary offsets, which
    are optional, left out (footer summary_offset_start 0), the footer's CRC made anew over the summary."""
    data = path.read_bytes()
    footer_at = len(data) - len(MAGIC) - _FOOTER.size
    op, _, start, _, _ = _FOOTER.unpack_from(data, footer_at)
    assert op == Opcode.FOOTER
    summary, pos = bytearray(), start
    while pos < footer_at:
        op, length = struct.unpack_from("<BQ", data, pos)
        if op == Opcode.CHUNK_INDEX:
            index = ChunkIndex.read(ReadDataStream(BytesIO(data[pos + 9:pos + 9 + length])))
            if index.chunk_start_offset == chunk_offset:
                del index.message_index_offsets[channel]
            builder = RecordBuilder()
            index.write(builder)
            summary += builder.end()
        elif op != Opcode.SUMMARY_OFFSET:
            summary += data[pos:pos + 9 + length]
        pos += 9 + length
    footer = _FOOTER.pack(Opcode.FOOTER, 20, start, 0, 0)[:-4]
    crc = zlib.crc32(bytes(summary) + footer)
    path.write_bytes(data[:start] + summary + footer + struct.pack("<I", crc) + MAGIC)


def _mcap_events(path: Path) -> int:
    """How many /events messages the mcap package's reader reads (it picks chunks by their indexes too)."""
    with open(path, "rb") as f:
        return sum(1 for _ in make_reader(f).iter_messages(topics=["/events"]))


def test_a_channel_a_chunk_index_leaves_out_is_damage_and_checked(tmp_path):
    record(tmp_path / "source", cycles=6, ticks_per_cycle=200, events=dict.fromkeys(EVENT_TICKS, "limit_intervention"))
    rewrite(tmp_path / "source", tmp_path / "crafted", edit=_malformed, chunk_size=16 << 10)
    path = tmp_path / "crafted" / "record.mcap"
    with open_record(path) as rec:  # as written: the malformed event is read, skipped and reported
        channel = rec._ids["/events"]
        assert len(list(rec.events())) == len(EVENT_TICKS) - 1
        assert rec.health().off_schema == {"/events": 1}
    bad_chunk = _chunk_holding_bad_event(path, channel)

    _leave_out(path, channel, bad_chunk)

    layout = scan(path)
    assert layout.finished  # the summary was read, not the file scanned
    listed = {ref.offset: ref.channels for ref in layout.chunks}
    assert channel not in listed[bad_chunk]
    assert sum(channel in ids for ids in listed.values()) == len(EVENT_TICKS) - 1  # the other events' chunks list it
    with open_record(path) as rec:
        assert len(list(rec.events())) == len(EVENT_TICKS) - 1 == _mcap_events(path)  # by the indexes, as mcap reads
        health = rec.health()
        assert health.off_schema == {"/events": 1}  # the one it left out, malformed
        assert [why for why in health.damage if "leave out" in why] == [
            f"chunk at byte {bad_chunk}: its message indexes leave out 1 /events message(s), which a read by the "
            f"indexes alone skips (read from the chunk itself here)"]
        assert health.unindexed == {"/events": 1}
        assert "1 /events message(s) missing from their chunks' message indexes" in health.describe()
        read = list(rec.events())
        assert [e.t_ns // DT_NS for e in read] == [k for k in EVENT_TICKS if k != BAD_TICK]
        assert rec.health().off_schema == {"/events": 1}  # noted once, however often read
