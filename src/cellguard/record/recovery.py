"""Rewrite a truncated or damaged record as a finished file, with a fresh summary and index.

The original is never modified: the recovered copy goes to another folder. Every message that
passed its chunk CRC is copied with its original times and sequence numbers (so the gaps stay
visible), into chunks of the usual span; the Parquet index is rebuilt from the cycle markers and
events that survived. A metadata record (``RECOVERED``) says what the source was, so the copy never
reads as a whole run (a record cut at its end has no gap to show: its copy read as complete).
"""

from __future__ import annotations

from pathlib import Path

from mcap.writer import CompressionType, Writer

from cellguard.errors import RecordError
from cellguard.record.index import IndexWriter, clear_index, cycle_row, event_row
from cellguard.record.reader import Health, open_record
from cellguard.record.schemas import CHANNELS
from cellguard.record.writer import INDEX_DIR, PROFILE, RECORD_FILE

CHUNK_SPAN_NS = 100_000_000  # recovered chunks hold this much log time
RECOVERED = "cellguard.recovered"  # metadata of a recovered copy: its source and what a full read of it found


def recover(source: Path, target: Path) -> Health:
    """Copy what is readable of ``source`` (folder or .mcap) into ``target/record.mcap`` and ``target/index``.

    Returns the health of the source as read; RecordError if nothing is readable or ``target``
    would overwrite the source.
    """
    source, target = Path(source), Path(target)
    with open_record(source) as record:
        if target.resolve() in (record.file.parent.resolve(), record.file.resolve()):
            raise RecordError(f"-o {target}: would overwrite the record being recovered; choose another folder")
        health = record.health()
        try:
            if (target / RECORD_FILE).exists():
                raise RecordError(f"-o {target}: already holds a record; recovery never overwrites one; "
                                  f"choose another folder")
            target.mkdir(parents=True, exist_ok=True)
            clear_index(target / INDEX_DIR)
            with open(target / RECORD_FILE, "wb") as f:
                _copy_messages(record, f, {"source": str(record.file), "source_health": health.describe()})
            _rebuild_index(record, target / INDEX_DIR)
        except OSError as exc:
            raise RecordError(f"{target}: cannot write the recovered record ({exc.strerror or exc})") from None
    return health


def _copy_messages(record, stream, recovered: dict[str, str]) -> None:
    writer = Writer(stream, chunk_size=1 << 30, compression=CompressionType.ZSTD, enable_crcs=True)
    writer.start(profile=PROFILE, library="cellguard record recover")
    for name, values in record.layout.metadata.items():  # foxglove, cellguard, cellguard.context
        if name != RECOVERED:  # a copy of a copy names the file it was made from
            writer.add_metadata(name, values)
    writer.add_metadata(RECOVERED, recovered)
    for name in record.layout.attachments:
        data = record.attachment(name)
        if data is not None:
            writer.add_attachment(record.start_wall_ns, record.start_wall_ns, name, "application/xml", data)
    for c in CHANNELS:
        schema = writer.register_schema(c.schema_name, c.schema_encoding, c.schema_text.encode())
        writer.register_channel(c.topic, c.message_encoding, schema)
    ids = {c.topic: c.id for c in CHANNELS}
    chunk_end = None
    for m in record.messages(list(ids)):
        if chunk_end is not None and m.log_time >= chunk_end:
            writer.flush()
            chunk_end = None
        if chunk_end is None:
            chunk_end = m.log_time + CHUNK_SPAN_NS
        writer.add_message(m.channel_id, m.log_time, m.data, m.publish_time, m.sequence)
    writer.finish()


def _rebuild_index(record, folder: Path) -> None:
    contexts = record.contexts
    where = {k: contexts[0].context.get(k) for k in ("site", "cell_id")} if contexts else {}
    index = IndexWriter(folder, record.epoch_wall_ns)
    for c in record.cycles():
        index.add("cycles", cycle_row(c.cycle, c.phase, c.t_start_ns, c.t_end_ns, c.success, {**c.versions, **where},
                                      c.features))
    for e in record.events():
        versions = next((x.versions for x in reversed(contexts) if x.t_ns <= e.t_ns), {})
        index.add("events", event_row(e.__dict__, e.cycle, {**versions, **where}))
    index.flush()
