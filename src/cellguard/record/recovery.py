"""Rewrite a truncated or damaged record as a finished file, with a fresh summary and index.

The original is never modified: the recovered copy goes to another folder. Every message that
passed its chunk CRC is copied with its original times and sequence numbers (so the gaps stay
visible), into chunks of the usual span and size; the Parquet index is rebuilt from the cycle
markers and events that survived (a malformed one is left out of it, as the reader skips it). A
metadata record (``RECOVERED``) says what the source was, so the copy never reads as a whole run (a
record cut at its end has no gap to show: its copy read as complete). The target must be a new or
empty folder; the copy is made in a hidden folder of its own inside it and moved into place once
whole: a recovery that fails leaves nothing.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

from mcap.writer import CompressionType, Writer

from cellguard.errors import RecordError
from cellguard.output import refuse_filled_folder
from cellguard.record.index import IndexWriter, cycle_row, event_row
from cellguard.record.reader import Health, open_record
from cellguard.record.schemas import CHANNELS
from cellguard.record.writer import CHUNK_BYTES, INDEX_DIR, PROFILE, RECORD_FILE

CHUNK_SPAN_NS = 100_000_000  # recovered chunks hold this much log time
RECOVERED = "cellguard.recovered"  # metadata of a recovered copy: its source and what a full read of it found


def recover(source: Path, target: Path) -> Health:
    """Copy what is readable of ``source`` (folder or .mcap) into ``target/record.mcap`` and ``target/index``.

    Returns the health of the source as read; RecordError if nothing is readable or ``target``
    would overwrite the source, OutputError if ``target`` is a folder that holds anything.
    """
    source, target = Path(source), Path(target)
    with open_record(source) as record:
        if target.resolve() in (record.file.parent.resolve(), record.file.resolve()):
            raise RecordError(f"-o {target}: would overwrite the record being recovered; choose another folder")
        refuse_filled_folder(target, "-o")  # another run's index parts there were cleared, its other files mixed in
        health = record.health()
        made, staging = False, None
        try:
            made = not target.exists()
            target.mkdir(parents=True, exist_ok=True)
            # inside the target: its files are renamed into place on the target's own filesystem (beside it, a
            # target that is a mount point failed with EXDEV, and a parent may not be writable)
            staging = Path(tempfile.mkdtemp(prefix=".recover-", suffix=".partial", dir=target))
            with open(staging / RECORD_FILE, "wb") as f:
                _copy_messages(record, f, {"source": _text(record.file), "source_health": health.describe()})
            _rebuild_index(record, staging / INDEX_DIR)
            _move_into(staging, target)
        except OSError as exc:
            raise RecordError(f"{target}: cannot write the recovered record ({exc.strerror or exc})") from None
        finally:  # this run's own folders: the staging one is empty once its files moved
            if staging is not None:
                shutil.rmtree(staging, ignore_errors=True)
            if made and not (target / RECORD_FILE).exists():
                shutil.rmtree(target, ignore_errors=True)
    return health


def _text(path: Path) -> str:
    """``path`` as text that any file can hold: a name that is not UTF-8 keeps its odd bytes as ``\\xff``."""
    return os.fsencode(path).decode("utf-8", "backslashreplace")


def _move_into(staging: Path, target: Path) -> None:
    """Move the copy's files from ``staging`` into ``target`` (empty but for ``staging``), the record last: a
    folder with a record reads as a finished copy, so the record appears only once its index is whole."""
    files = sorted((p for p in staging.rglob("*") if p.is_file()), key=lambda p: p.name == RECORD_FILE)
    for file in files:
        destination = target / file.relative_to(staging)
        destination.parent.mkdir(parents=True, exist_ok=True)
        file.rename(destination)


def _copy_messages(record, stream, recovered: dict[str, str]) -> None:
    writer = Writer(stream, chunk_size=1 << 30, compression=CompressionType.ZSTD, enable_crcs=True)
    writer.start(profile=PROFILE, library="cellguard record recover")
    for name, values in record.layout.metadata.items():  # foxglove, cellguard, cellguard.context
        if name in ("cellguard", "cellguard.context"):  # the format, epoch and start the contexts state
            values = {**values, **record.facts()}
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
    chunk_end, size = None, 0
    for m in record.messages(list(ids)):
        if chunk_end is not None and (m.log_time >= chunk_end or size >= CHUNK_BYTES):  # a backlog shares one time
            writer.flush()
            chunk_end, size = None, 0
        if chunk_end is None:
            chunk_end = m.log_time + CHUNK_SPAN_NS
        writer.add_message(m.channel_id, m.log_time, m.data, m.publish_time, m.sequence)
        size += len(m.data)
    writer.finish()


def _rebuild_index(record, folder: Path) -> None:
    contexts = record.contexts
    where = {k: contexts[0].context.get(k) for k in ("site", "cell_id")} if contexts else {}
    index = IndexWriter(folder, record.epoch_wall_ns, record_id=record.record_id)
    for c in record.cycles():
        index.add("cycles", cycle_row(c.cycle, c.phase, c.t_start_ns, c.t_end_ns, c.success, {**c.versions, **where},
                                      c.features))
    for e in record.events():
        versions = next((x.versions for x in reversed(contexts) if x.t_ns <= e.t_ns), {})
        index.add("events", event_row(e.__dict__, e.cycle, {**versions, **where}))
    index.flush()
