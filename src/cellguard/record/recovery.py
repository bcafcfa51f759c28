"""Rewrite a truncated or damaged record as a finished file, with a fresh summary and index.

The original is never modified: the recovered copy goes to another folder. Every message that passed its chunk CRC is
copied with its original times and sequence numbers (so the gaps stay visible), under its topic's channel numbered as
the recorder numbers it (not the source's id: a record rewritten by another MCAP writer numbers its channels
otherwise, and its copy filed every message under another topic), into chunks of the usual span and size; the Parquet
index is rebuilt from the cycle markers and events that survived (a malformed one is left out of it, as the reader
skips it). A metadata record (``RECOVERED``) says what the source was, so the copy never reads as a whole run (a
record cut at its end has no gap to show: its copy read as complete). The copy is of its source's format, stated in
its ``cellguard`` metadata, with that format's channels: a format-1 record (no metadata, log times on the run clock)
stays format 1. The target must be a new or empty folder; the copy is made in a hidden folder of its own inside it and
moved into place once whole: a recovery that fails leaves nothing. The staging folder is locked (``folder_lock``)
while its process lives, so a second recovery into the same folder sees a live one (refused) or the leftovers of a
killed one (removed); the final move happens under the target's lock, after the target is checked again, and links
each file into place (never a rename over one): two recoveries started together both ended 0, one copy replaced.
"""

from __future__ import annotations

import errno
import os
import shutil
import tempfile
from pathlib import Path

from mcap.writer import CompressionType, Writer

from cellguard.errors import RecordError
from cellguard.output import refuse_filled_folder
from cellguard.record import folder_lock, staged
from cellguard.record.index import IndexWriter, cycle_row, event_row
from cellguard.record.reader import Health, open_record
from cellguard.record.schemas import CHANNELS, OWN_TOPICS, ChannelSpec
from cellguard.record.writer import CHUNK_BYTES, INDEX_DIR, PROFILE, RECORD_FILE

CHUNK_SPAN_NS = 100_000_000  # recovered chunks hold this much log time
RECOVERED = "cellguard.recovered"  # metadata of a recovered copy: its source and what a full read of it found


def recover(source: Path, target: Path) -> Health:
    """Copy what is readable of ``source`` (folder or .mcap) into ``target/record.mcap`` and ``target/index``.

    Returns the health of the source as read; RecordError if nothing is readable, a run is still writing the source
    or ``target`` would overwrite it, OutputError if ``target`` is a folder that holds anything.
    """
    source, target = Path(source), Path(target)
    with open_record(source) as record:
        if record.writing:  # a copy of what is written so far read as the recovery of a truncated record
            raise RecordError(f"{source}: still being written by {record.writing}; nothing was copied: wait for it "
                              f"to end, it finishes the record itself (recover it then only if it is left truncated)")
        if target.resolve() in (record.file.parent.resolve(), record.file.resolve()):
            raise RecordError(f"-o {target}: would overwrite the record being recovered; choose another folder")
        # another run's index parts there were cleared, its other files mixed in
        refuse_filled_folder(target, "-o", _clear_stale_staging(target))
        health = record.health()
        made, staging, lock, refused = False, None, None, False
        try:
            made = not target.exists()
            target.mkdir(parents=True, exist_ok=True)
            # inside the target: its files are renamed into place on the target's own filesystem (beside it, a
            # target that is a mount point failed with EXDEV, and a parent may not be writable)
            staging = Path(tempfile.mkdtemp(prefix=STAGING[0], suffix=STAGING[1], dir=target))
            lock = folder_lock.hold(staging, "-o", wait_s=0)  # made just now: no hold to wait out
            with open(staging / RECORD_FILE, "wb") as f:
                _copy_messages(record, f, {"source": _text(record.file), "source_health": health.describe()})
            _rebuild_index(record, staging / INDEX_DIR)
            _move_into(staging, target, staged.note_files(staging))  # a rerun after a kill takes out what it moved
        except BaseException as exc:
            if staging is not None:
                # cut short in its moves: none of the copy is left, or (a file not its own there) its note stays
                refused = not staged.take_back(staging, target, _staging)
            if isinstance(exc, OSError):
                raise RecordError(f"{target}: cannot write the recovered record ({exc.strerror or exc})") from None
            raise
        finally:  # this run's own folders: the staging one is empty once its files moved
            if staging is not None and not refused:
                shutil.rmtree(staging, ignore_errors=True)
            folder_lock.release(lock)
            if made and not (target / RECORD_FILE).exists():
                try:
                    target.rmdir()  # only if empty: another recovery's staging folder may be in it
                except OSError:
                    pass
    return health


MOVE_WAIT_S = 10.0  # [s] how long a recovery waits for the target's lock before its move (another recovery's move)
STAGING = (".recover-", ".partial")  # prefix and suffix of a recovery's staging folder inside its target


def _staging(path: Path) -> bool:
    return path.name.startswith(STAGING[0]) and path.name.endswith(STAGING[1]) and path.is_dir() \
        and not path.is_symlink()


def _clear_stale_staging(target: Path) -> str:
    """Remove the staging folders of recoveries killed in ``target`` (nothing holds their lock), and the files one had
    moved into ``target`` before it was killed where it holds nothing else (``staged``); RecordError if a recovery is
    still writing there. A rerun after ``kill -9`` was refused as "not empty", saying nothing of why. Returns what to
    say of the ones kept (``staged.clear_killed``)."""
    try:
        leftovers = [p for p in target.iterdir() if _staging(p)] if target.is_dir() else []
    except OSError:
        return ""  # refuse_filled_folder says why the folder cannot be read
    return staged.clear_killed(leftovers, target, f"-o {target}: another recovery is writing there", _staging)


def _text(path: Path) -> str:
    """``path`` as text that any file can hold: a name that is not UTF-8 keeps its odd bytes as ``\\xff``."""
    return os.fsencode(path).decode("utf-8", "backslashreplace")


def _move_into(staging: Path, target: Path, files: list[Path]) -> None:
    """Move the copy's ``files`` (relative) from ``staging`` into ``target`` (empty but for staging folders), the record
    last: a folder with a record reads as a finished copy, so the record appears only once its index is whole. Under
    the target's lock, after looking again; each file is linked into place (a file there is never replaced)."""
    lock = folder_lock.hold(target, "-o", wait_s=MOVE_WAIT_S)  # another recovery's move is short; a run's life is not
    try:
        filled = sorted(p.name for p in target.iterdir() if not _staging(p))
        if filled:
            raise RecordError(f"-o {target}: {filled[0]} appeared there while the copy was made (another recovery?); "
                              f"nothing of it was replaced: give a new folder")
        for name in sorted(files, key=lambda p: p == Path(RECORD_FILE)):
            file, destination = staging / name, target / name
            destination.parent.mkdir(parents=True, exist_ok=True)
            try:
                os.link(file, destination)
            except OSError as exc:
                if exc.errno not in (errno.EPERM, errno.EOPNOTSUPP, errno.ENOTSUP, errno.EMLINK):
                    raise  # EEXIST above all: never replaced
                file.rename(destination)  # a filesystem without hard links: under the lock, checked empty
                continue
            file.unlink()
    finally:
        folder_lock.release(lock)


def _copy_messages(record, stream, recovered: dict[str, str]) -> None:
    writer = Writer(stream, chunk_size=1 << 30, compression=CompressionType.ZSTD, enable_crcs=True)
    writer.start(profile=PROFILE, library="cellguard record recover")
    # foxglove, cellguard, cellguard.context; format 1 has none, and its copy must state it is format 1 (a copy
    # with no format and ROS 2 channels read as format 2 whose metadata was lost: its spans were years off)
    for name, values in {"cellguard": {}, **record.layout.metadata}.items():
        if name in ("cellguard", "cellguard.context"):  # the format, epoch and start the contexts state
            values = {**values, **record.facts()}
        if name != RECOVERED:  # a copy of a copy names the file it was made from
            writer.add_metadata(name, values)
    writer.add_metadata(RECOVERED, recovered)
    for name in record.layout.attachments:
        data = record.attachment(name)
        if data is not None:
            writer.add_attachment(record.start_wall_ns, record.start_wall_ns, name, "application/xml", data)
    channels, ids = _channels(record.version), {}  # ids: the source's channel id -> the copy's, by topic
    for c in channels:
        schema = writer.register_schema(c.schema_name, c.schema_encoding, c.schema_text.encode())
        ids[record.channel_id(c.topic)] = writer.register_channel(c.topic, c.message_encoding, schema)
    chunk_end, size = None, 0
    for m in record.messages([c.topic for c in channels]):
        if chunk_end is not None and (m.log_time >= chunk_end or size >= CHUNK_BYTES):  # a backlog shares one time
            writer.flush()
            chunk_end, size = None, 0
        if chunk_end is None:
            chunk_end = m.log_time + CHUNK_SPAN_NS
        writer.add_message(ids[m.channel_id], m.log_time, m.data, m.publish_time, m.sequence)
        size += len(m.data)
    writer.finish()


def _channels(version: int) -> tuple[ChannelSpec, ...]:
    """The channels of a record of format ``version``: the ROS 2 ones, from ``/joint_states`` on, came with format 2
    (the reader takes them for its sign), so a format-1 copy has cellguard's own channels only, as its source."""
    return CHANNELS if version >= 2 else tuple(c for c in CHANNELS if c.topic in OWN_TOPICS)


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
