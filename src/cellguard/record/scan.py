"""Where the chunks of an MCAP file are, even when the file is truncated or damaged.

The fast path reads the summary at the end of a finished file, after checking its CRC (any
chunk it points at is still checked against its own CRC when read). When the summary is
missing (a crash, a full disk) or wrong, a linear scan walks the records from the start the way
``mcap.stream_reader.StreamReader`` does, but does not stop at the first bad record: a chunk
whose CRC, compression or length is wrong is noted as damage, and the scan resynchronises on the
next chunk header it can find (``0x06``, length, times, ``zstd``). A chunk followed by sound message
indexes naming channels already declared is laid out from them, not decompressed (a cut record of
2,700 chunks was decompressed whole at open, for a window of a few), and checked against its CRC
when it is read (``Record`` notes it as damage then); every other chunk it keeps has passed its CRC.
Messages carry per-channel sequence numbers, so a lost chunk shows as a gap.

A chunk is decompressed only up to the size it declares, and one that declares more than
``MAX_CHUNK_BYTES`` is damage: the recorder's chunks hold about 1 MiB, and a few kilobytes of zstd
or lz4 can declare (or expand to) gigabytes.
"""

from __future__ import annotations

import mmap
import os
import stat
import struct
import threading
import zlib
from dataclasses import dataclass, field, replace
from io import BytesIO
from pathlib import Path

import lz4.frame
import numpy as np
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import AttachmentIndex, Channel, Chunk, Message, Metadata, MetadataIndex, Schema, Statistics
from mcap.stream_reader import breakup_chunk, get_chunk_data_stream

from cellguard.errors import RecordError
from cellguard.record.writer import CHUNK_BYTES, LIBRARY

MAGIC = b"\x89MCAP0\r\n"
_VALID_OPCODES = {int(op) for op in Opcode}
_CHUNK_SIGNATURE = b"\x04\x00\x00\x00zstd"  # compression string of a zstd chunk
_SIGNATURE_OFFSET = 1 + 8 + 8 + 8 + 8 + 4  # opcode, length, start, end, size, crc
_HEAD = struct.Struct("<BQQQ")  # opcode, length, message_start_time, message_end_time
_FOOTER = struct.Struct("<BQQQI")  # opcode, length, summary_start, summary_offset_start, summary_crc
_CHUNK_INDEX = struct.Struct("<QQQQI")  # start, end, chunk offset, chunk length, bytes of channel offsets
_RECORD = struct.Struct("<BQ")  # opcode, length of the record that follows
_MESSAGE = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time; then the data
_CHUNK_SIZE = struct.Struct("<Q")  # a chunk's uncompressed size, after opcode, length and its two times
_INDEX_HEAD = struct.Struct("<QHI")  # a message index: record length, channel id, bytes of (log time, offset) pairs
MAX_CHUNK_BYTES = 16 * CHUNK_BYTES  # [bytes] the most a chunk may hold uncompressed, and so any one message
FAULT_AROUND = 64 << 10  # [bytes] Linux maps up to this many bytes around a page fault (fault_around_bytes)
_THREAD = threading.local()  # what each thread keeps for itself (its zstd decompressor)


@dataclass(frozen=True)
class ChunkRef:
    """A chunk record: ``offset`` of its opcode, ``length`` of the whole record, its message times."""

    offset: int
    length: int
    start_ns: int
    end_ns: int
    channels: frozenset[int] | None = None  # None: not known without decompressing


@dataclass(frozen=True)
class Damage:
    offset: int
    why: str
    at_end: bool = False  # the file ends inside this record: its last bytes are not written (yet, in a live record)


@dataclass
class Layout:
    """The chunks of one file and what is wrong with it."""

    path: Path
    size: int
    chunks: list[ChunkRef]
    damage: list[Damage] = field(default_factory=list)
    finished: bool = False  # a footer and a usable summary were found
    truncated: bool = False  # the file ends inside a record or without a footer
    own: bool = False  # its header names cellguard's recorder as the library that wrote it (``_indexed``)
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)  # name -> key/values (the last of a name)
    attachments: dict[str, tuple[int, int]] = field(default_factory=dict)  # name -> (offset, length) of the record
    counts: dict[int, int] | None = None  # channel id -> messages in the file, by the summary's statistics (None: none)

    @property
    def topics(self) -> dict[int, str]:
        """Channel id -> topic, as the channel records read state them."""
        return {i: c.topic for i, c in self.channels.items()}

    @property
    def schema_names(self) -> dict[int, str]:
        """Channel id -> the name of the schema it declares, where that schema's record was read ("": none, id 0)."""
        return {i: self.schemas[c.schema_id].name if c.schema_id else "" for i, c in self.channels.items()
                if not c.schema_id or c.schema_id in self.schemas}


def scan(path: Path) -> Layout:
    """The layout of ``path``: from its summary if that is sound, else by a linear scan."""
    path = Path(path)
    require_regular(path, "the record")
    try:
        with open(path, "rb") as f:
            data = f.read(len(MAGIC))
            size = f.seek(0, 2)
    except OSError as exc:
        raise RecordError(f"{path}: cannot open the record ({exc.strerror or exc})") from None
    if size == 0:
        raise RecordError(f"{path}: the record is empty (0 bytes); nothing can be recovered")
    try:
        layout = _from_summary(path, size) if data == MAGIC else None
    except Exception:  # noqa: BLE001 - a summary that parses badly despite its CRC: scan the file instead
        layout = None
    try:
        if layout is not None and not layout.chunks:  # chunk indexes are optional (MCAP spec; mcap's Writer with
            # IndexType.NONE): the chunks of a finished file found by a scan
            return replace(_linear(path, size, magic_ok=True), finished=True, counts=layout.counts)
        return layout if layout is not None else _linear(path, size, magic_ok=data == MAGIC)
    except (OSError, ValueError, struct.error) as exc:
        raise RecordError(f"{path}: cannot be read ({type(exc).__name__}: {exc})") from None


def stated_record_id(path: Path) -> str | None:
    """The record id the ``cellguard`` metadata record at the start of ``path`` states, or None: read from the
    records before the first chunk, so nothing is decompressed (a truncated file has no summary to look in)."""
    layout = Layout(path, 0, [])
    try:
        with open_buffer(path) as buf:
            pos = len(MAGIC)
            while pos + 9 <= len(buf) and buf[pos] in (Opcode.HEADER, Opcode.METADATA):
                if buf[pos] == Opcode.METADATA:
                    _metadata(buf, pos, layout)
                pos += 9 + int.from_bytes(buf[pos + 1:pos + 9], "little")
    except (OSError, ValueError):  # ValueError: an empty file cannot be mapped
        return None
    return layout.metadata.get("cellguard", {}).get("record_id")


def require_regular(path: Path, what: str) -> None:
    """RecordError if ``path`` exists but is not a regular file: opening a FIFO waits for a writer that
    may never come and a device may never end, so neither is opened (a missing file is left to the open)."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return
    if not stat.S_ISREG(mode):
        raise RecordError(f"{path}: {what} is not a regular file (a folder, FIFO, socket or device); "
                          f"nothing was read from it")


def read_chunk(buf, ref: ChunkRef, channels: set[int] | None = None, heads: list | None = None) -> list:
    """The records inside one chunk (schemas, channels, messages); RecordError if it is damaged.
    ``channels``: only the messages of these channel ids, read without decoding the others (a
    chunk of an arm record holds some 30 tick and state messages besides one cycle's); ``heads``, with
    ``channels``: a list that gets (channel id, sequence, log time, publish time) of every message in the chunk,
    if it is not damaged (a count of all messages needs no more)."""
    raw = buf[ref.offset:ref.offset + ref.length]
    if len(raw) < ref.length or raw[0] != Opcode.CHUNK:
        raise RecordError(f"chunk at byte {ref.offset}: not a chunk record")
    _release(buf, ref.offset, ref.length)
    try:
        chunk = Chunk.read(ReadDataStream(BytesIO(raw[9:])))
        if chunk.compression not in ("zstd", "lz4", ""):
            raise RecordError(f"chunk at byte {ref.offset}: unknown compression {chunk.compression!r}")
        if chunk.uncompressed_size > MAX_CHUNK_BYTES:
            raise RecordError(f"chunk at byte {ref.offset}: declares {chunk.uncompressed_size} bytes uncompressed, "
                              f"over the limit of {MAX_CHUNK_BYTES}; not decompressed")
        chunk = replace(chunk, compression="", data=_decompressed(chunk))
        if channels is None:
            return breakup_chunk(chunk, validate_crc=True)
        stream, size = get_chunk_data_stream(chunk, validate_crc=True)
        messages, every = _messages(stream.read(size), channels)
        if heads is not None:
            heads += every
        return messages
    except RecordError:
        raise
    except Exception as exc:  # the mcap package raises many kinds on a corrupt chunk (zstd, CRC, struct)
        raise RecordError(f"chunk at byte {ref.offset}: damaged ({type(exc).__name__}: {exc})") from None


def _decompressed(chunk: Chunk) -> bytes:
    """The chunk's records, never more than the size it declares: ValueError if they are not that size
    (mcap's own reader allocates whatever a zstd frame header states and expands lz4 without a limit)."""
    limit = chunk.uncompressed_size + 1  # one byte more tells a chunk that expands past its size
    if chunk.compression == "zstd":
        with _zstd().stream_reader(chunk.data) as stream:
            data = stream.read(limit)
    elif chunk.compression == "lz4":
        data = lz4.frame.LZ4FrameDecompressor().decompress(chunk.data, max_length=limit)
    else:
        data = chunk.data
    if len(data) != chunk.uncompressed_size:
        raise ValueError(f"{'more' if len(data) == limit else len(data)} bytes where it declares "
                         f"{chunk.uncompressed_size}")
    return data


def _zstd() -> zstandard.ZstdDecompressor:
    """This thread's zstd decompressor, made once: a new one per chunk took 0.2 s of a 196 MB record's read. One per
    thread, as one instance must not decompress for two threads at once (each use starts from a reset context, so a
    damaged chunk leaves nothing behind for the next)."""
    zstd = getattr(_THREAD, "zstd", None)
    if zstd is None:
        zstd = _THREAD.zstd = zstandard.ZstdDecompressor()
    return zstd


def _release(buf, offset: int, length: int) -> None:
    """Unmap the pages of bytes already copied out of the file's mapping: mapped, every page read stays in the
    process (reading a record end to end held all of it); a later read maps them again from the page cache.
    The whole ``FAULT_AROUND`` windows the bytes lie in: the kernel maps a fault's neighbours too, and those
    before a chunk, never unmapped, held most of the file again (221 MB to read an 85 MB record)."""
    if isinstance(buf, mmap.mmap) and hasattr(mmap, "MADV_DONTNEED"):
        start = offset - offset % FAULT_AROUND
        end = min(len(buf), -(-(offset + length) // FAULT_AROUND) * FAULT_AROUND)
        buf.madvise(mmap.MADV_DONTNEED, start, end - start)


def _messages(data: bytes, channels: set[int]) -> tuple[list[Message], list[tuple[int, int, int, int]]]:
    """The messages of ``channels`` in a chunk's uncompressed records, and the heads (channel id, sequence, log time,
    publish time) of all messages, in file order; ValueError if a record runs past the end."""
    out, heads, at, end = [], [], 0, len(data)
    while at < end:
        op, length = _RECORD.unpack_from(data, at)
        body = at + _RECORD.size
        if body + length > end:
            raise ValueError(f"a record of {length} bytes runs past the chunk's end")
        if op == Opcode.MESSAGE:
            head = channel, sequence, log_time, publish_time = _MESSAGE.unpack_from(data, body)
            heads.append(head)
            if channel in channels:
                out.append(Message(channel_id=channel, log_time=log_time, data=data[body + _MESSAGE.size:body + length],
                                   publish_time=publish_time, sequence=sequence))
        at = body + length
    return out, heads


def read_attachment(buf, offset: int, length: int):
    """The attachment record at ``offset`` (its CRC checked), or None if it is damaged."""
    from mcap.records import Attachment

    try:
        if buf[offset] != Opcode.ATTACHMENT:
            return None
        record = Attachment.read(ReadDataStream(BytesIO(buf[offset + 9:offset + length])))
    except Exception:  # noqa: BLE001 - damaged bytes
        return None
    return record


def open_buffer(path: Path):
    """A read-only view of the whole file (memory-mapped)."""
    with open(path, "rb") as f:
        return mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)


def _from_summary(path: Path, size: int) -> Layout | None:
    """The chunk indexes of a finished file whose summary CRC holds; None means: scan instead.

    Parsed here rather than with ``make_reader().get_summary()``: a 100 ms chunk makes 36,000
    chunk indexes an hour, and the generic record reader takes a second over them.
    """
    footer_at = size - len(MAGIC) - _FOOTER.size
    with open_buffer(path) as buf:
        if footer_at <= len(MAGIC) or buf[size - len(MAGIC):] != MAGIC:
            return None
        op, length, start, _, crc = _FOOTER.unpack_from(buf, footer_at)
        if op != Opcode.FOOTER or length != 20 or not len(MAGIC) < start <= footer_at or crc == 0:
            return None
        if zlib.crc32(buf[start:footer_at + 25]) != crc:  # the summary and the footer's offsets
            return None
        layout = Layout(path, size, [], finished=True)
        pos, id_sets = start, {}  # the chunks of a record share a few channel sets: each parsed once
        while pos + 9 <= footer_at:
            op, length = _RECORD.unpack_from(buf, pos)
            if op == Opcode.CHUNK_INDEX:  # read in place: an hour holds some 36,000 of them
                t0, t1, offset, chunk_length, ids_length = _CHUNK_INDEX.unpack_from(buf, pos + 9)
                entries = buf[pos + 45:pos + 45 + ids_length]  # (channel id u16, offset u64) each
                key = (entries[0::10], entries[1::10])  # the ids' low and high bytes, without the offsets
                ids = id_sets.get(key)
                if ids is None:  # none: a file written without message indexes, its channels unknown (MCAP spec)
                    ids = id_sets[key] = frozenset(low | high << 8 for low, high in zip(*key)) or None
                layout.chunks.append(ChunkRef(offset, chunk_length, t0, t1, ids))
                pos += 9 + length
                continue
            body = buf[pos + 9:pos + 9 + length]
            if op == Opcode.SCHEMA:
                schema = Schema.read(ReadDataStream(BytesIO(body)))
                layout.schemas[schema.id] = schema
            elif op == Opcode.CHANNEL:
                channel = Channel.read(ReadDataStream(BytesIO(body)))
                layout.channels[channel.id] = channel
            elif op == Opcode.METADATA_INDEX:
                entry = MetadataIndex.read(ReadDataStream(BytesIO(body)))
                _metadata(buf, entry.offset, layout)
            elif op == Opcode.ATTACHMENT_INDEX:
                entry = AttachmentIndex.read(ReadDataStream(BytesIO(body)))
                layout.attachments[entry.name] = (entry.offset, entry.length)
            elif op == Opcode.STATISTICS:
                layout.counts = Statistics.read(ReadDataStream(BytesIO(body))).channel_message_counts
            pos += 9 + length
    layout.chunks.sort(key=lambda r: r.offset)
    return layout


def _linear(path: Path, size: int, magic_ok: bool) -> Layout:
    layout = Layout(path, size, [], truncated=True)
    with open_buffer(path) as buf:
        pos, floor, tried = len(MAGIC), len(MAGIC), set()
        if not magic_ok:
            layout.damage.append(Damage(0, "the file does not start with the MCAP magic"))
            pos = _resync(buf, 0, tried)
        while pos + 9 <= size:
            op, length = buf[pos], int.from_bytes(buf[pos + 1:pos + 9], "little")
            end = pos + 9 + length
            if op not in _VALID_OPCODES or end > size:
                tried.add(pos)
                nxt = _resync(buf, floor, tried)
                if nxt >= size:  # nothing after: the file was cut here
                    layout.damage.append(Damage(pos, "truncated: the file ends inside a record", True)
                                         if op in _VALID_OPCODES else Damage(pos, "unreadable bytes up to the end"))
                    break
                layout.damage.append(Damage(pos, f"unreadable bytes up to byte {nxt}"))
                pos = nxt
                continue
            if op == Opcode.CHUNK:
                ref = _check_chunk(buf, pos, length, layout)
                if ref is None:
                    tried.add(pos)
                    pos = _resync(buf, pos + 1, tried)
                    continue
                floor = end
            elif op == Opcode.METADATA:
                _metadata(buf, pos, layout)
            elif op == Opcode.HEADER:
                library_at = pos + 13 + int.from_bytes(buf[pos + 9:pos + 13], "little")  # after its profile
                layout.own = _string(buf, library_at, end) == LIBRARY
            elif op == Opcode.ATTACHMENT:
                name = _attachment_name(buf, pos)
                if name is not None:
                    layout.attachments[name] = (pos, end - pos)
            elif op == Opcode.FOOTER:
                layout.truncated = end + len(MAGIC) > size or buf[end:end + len(MAGIC)] != MAGIC
                break
            pos = end
    return layout


def _metadata(buf, pos: int, layout: Layout) -> None:
    """Read the metadata record at ``pos`` into the layout; a damaged one is noted, not raised."""
    try:
        if buf[pos] != Opcode.METADATA:
            raise ValueError("not a metadata record")
        length = int.from_bytes(buf[pos + 1:pos + 9], "little")
        record = Metadata.read(ReadDataStream(BytesIO(buf[pos + 9:pos + 9 + length])))
        layout.metadata[record.name] = dict(record.metadata)
    except Exception as exc:  # noqa: BLE001 - any parse failure of damaged bytes is damage, not a crash
        layout.damage.append(Damage(pos, f"metadata record at byte {pos}: unreadable ({type(exc).__name__})"))


def _attachment_name(buf, pos: int) -> str | None:
    """The name of the attachment record at ``pos`` (after log and create times), or None if unreadable."""
    try:
        size = int.from_bytes(buf[pos + 25:pos + 29], "little")
        return bytes(buf[pos + 29:pos + 29 + size]).decode()
    except (ValueError, UnicodeDecodeError):
        return None


def _check_chunk(buf, pos: int, length: int, layout: Layout) -> ChunkRef | None:
    """The chunk at ``pos`` as a ChunkRef (in ``layout``), its channels and times from the message indexes after it
    where they are sound and name known channels (nothing decompressed: a window read of a cut record decompressed
    every chunk of it at open; such a chunk's CRC is checked when it is read), else from its records (which also
    declare the schemas and channels); None if it is damaged (noted)."""
    indexed = _indexed(buf, pos, length, layout)
    if indexed is not None:
        ref = ChunkRef(pos, 9 + length, *indexed)
        layout.chunks.append(ref)
        return ref
    _, _, start, end = _HEAD.unpack_from(buf, pos)
    ref = ChunkRef(pos, 9 + length, start, end)
    try:
        records = read_chunk(buf, ref)
    except RecordError as exc:
        layout.damage.append(Damage(pos, str(exc)))
        return None
    channels, times = set(), []
    for record in records:
        if isinstance(record, Message):
            channels.add(record.channel_id)
            times.append(record.log_time)
        elif isinstance(record, Schema):
            layout.schemas[record.id] = record
        elif isinstance(record, Channel):
            layout.channels[record.id] = record
    ref = ChunkRef(pos, 9 + length, min(times, default=start), max(times, default=end), frozenset(channels))
    layout.chunks.append(ref)
    return ref


def _indexed(buf, pos: int, length: int, layout: Layout) -> tuple[int, int, frozenset[int]] | None:
    """(first, last log time, channel ids) of the chunk at ``pos`` by the message index records that follow it, or
    None: the chunk's head is not a whole chunk of a known compression and size, no index follows (a file cut
    there), an index runs past the file or points past the chunk's records, or names a channel not yet declared, its
    times lie outside the chunk's own, or the file ends in or right after them (an index of the chunk may be missing).
    Only in cellguard's own records (``layout.own``): its recorder declares every channel in its first chunk, which
    is decompressed (its indexes name channels not declared yet); mcap's own Writer declares a channel in the chunk
    where it is registered, which may hold no message of it, and so no index that would say so."""
    end = pos + 9 + length
    if length < 40 or not layout.own:  # times, size, CRC, an empty compression and the records' length
        return None
    uncompressed, compression = _CHUNK_SIZE.unpack_from(buf, pos + 25)[0], _string(buf, pos + 37, end)
    if compression not in ("zstd", "lz4", "") or uncompressed > MAX_CHUNK_BYTES:
        return None
    records_at = pos + 41 + len(compression)
    if records_at + 8 > end or records_at + 8 + int.from_bytes(buf[records_at:records_at + 8], "little") != end:
        return None
    channels, pairs, at = set(), [], end
    while at + 15 <= len(buf) and buf[at] == Opcode.MESSAGE_INDEX:
        size, channel, entries = _INDEX_HEAD.unpack_from(buf, at + 1)
        if size != 6 + entries or entries % 16 or at + 9 + size > len(buf) or channel not in layout.channels:
            return None
        if entries:
            channels.add(channel)
            pairs.append(buf[at + 15:at + 15 + entries])
        at += 9 + size
    if not pairs or at + 9 > len(buf) or buf[at] == Opcode.MESSAGE_INDEX or buf[at] not in _VALID_OPCODES:
        return None  # cut in or right after them: an index of the chunk may be missing
    times, offsets = np.frombuffer(b"".join(pairs), "<u8").reshape(-1, 2).T  # (log time, offset) each
    _, _, first, last = _HEAD.unpack_from(buf, pos)
    if offsets.max() >= uncompressed or times.min() < first or times.max() > last:  # the chunk's head disagrees
        return None
    return int(times.min()), int(times.max()), frozenset(channels)


def _string(buf, at: int, end: int) -> str | None:
    """The MCAP string (u32 length, UTF-8) at ``at``, None if it runs past ``end`` or is not UTF-8."""
    if at + 4 > end:
        return None
    size = int.from_bytes(buf[at:at + 4], "little")
    try:
        return bytes(buf[at + 4:at + 4 + size]).decode() if at + 4 + size <= end else None
    except UnicodeDecodeError:
        return None


def _resync(buf, start: int, tried: set[int]) -> int:
    """Offset of the next plausible chunk record at or after ``start`` not tried before, else the size."""
    i = buf.find(_CHUNK_SIGNATURE, start + _SIGNATURE_OFFSET)
    while i != -1:
        candidate = i - _SIGNATURE_OFFSET
        if candidate not in tried and buf[candidate] == Opcode.CHUNK:
            return candidate
        i = buf.find(_CHUNK_SIGNATURE, i + 1)
    return len(buf)
