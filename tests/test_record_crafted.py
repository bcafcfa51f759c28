"""Records crafted to hurt a reader: compression bombs, metadata and context of the wrong kind, out-of-range index
rows, names that are not UTF-8, link loops. Each is read with what can be read, reported as damage or refused in one
line; nothing takes the machine's memory, stops with a traceback or leaves a half-made output."""

from __future__ import annotations

import os
import shutil
import struct
import zlib
from pathlib import Path

import lz4.frame
import pyarrow.parquet as pq
import pytest
import zstandard
from cli_util import one_error
from record_synth import record, rewrite
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.record import recovery, scan
from cellguard.record import reader as reader_module
from cellguard.record.reader import open_record
from cellguard.record.recovery import recover

runner = CliRunner()
_EPOCH = 1_790_000_000_000_000_000  # record_synth's
_YEAR_NS = 365 * 86400 * 10**9


@pytest.fixture(scope="module")
def original(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("orig")
    record(out, 4, 1000, events={1500: "position_clamp"})
    return out


def _data_end(data: bytes) -> int:
    """Offset of the DataEnd record: where the data section ends and the summary starts."""
    pos = len(scan.MAGIC)
    while data[pos] != 0x0F:
        pos += 9 + struct.unpack_from("<Q", data, pos + 1)[0]
    return pos


def _chunk(payload: bytes, compression: str, declared: int) -> bytes:
    """A chunk record holding one /cycles message of ``payload``, compressed, declaring ``declared`` bytes."""
    t = _EPOCH + 10**9
    records = struct.pack("<BQHIQQ", 5, 22 + len(payload), 6, 10**6, t, t) + payload
    compress = {"zstd": zstandard.ZstdCompressor().compress, "lz4": lz4.frame.compress}[compression]
    data = compress(records)
    body = (struct.pack("<QQQI", t, t, declared, zlib.crc32(records)) + struct.pack("<I", len(compression))
            + compression.encode() + struct.pack("<Q", len(data)) + data)
    return struct.pack("<BQ", 6, len(body)) + body


@pytest.mark.parametrize(("compression", "size", "declared"), [
    ("zstd", 17 << 20, None),  # declares what it holds, over the limit of 16 MiB
    ("lz4", 4 << 20, 1000),  # declares 1000 bytes and expands to 4 MiB
    ("zstd", 4 << 20, 1000),
])
def test_a_compression_bomb_is_a_damaged_chunk(original, tmp_path, compression, size, declared):
    data = (original / "record.mcap").read_bytes()
    bomb = _chunk(b" " * size, compression, size + 31 if declared is None else declared)
    (tmp_path / "record.mcap").write_bytes(data[:_data_end(data)] + bomb)
    with open_record(tmp_path) as rec:
        health = rec.health()
        assert len(rec.ticks(cycle=1)) == 1000
    assert health.chunks_damaged == 1 and not health.ok
    assert any(("over the limit" if declared is None else "where it declares 1000") in d for d in health.damage)


@pytest.mark.parametrize("fact", ["epoch_wall_ns", "record_version", "start_ns"])
def test_metadata_numbers_in_other_digits_are_damage_not_a_traceback(original, tmp_path, fact):
    rewrite(original, tmp_path, metadata={"cellguard": {fact: "\u00b2"}})  # "²".isdigit() holds
    with open_record(tmp_path) as rec:
        health = rec.health()
        assert len(rec.ticks(cycle=1)) == 1000 and rec.version == 2 and rec.epoch_wall_ns == _EPOCH
    assert not health.ok and f"{fact} '\u00b2'" in health.describe()


@pytest.mark.parametrize("fact", ["epoch_wall_ns", "record_version", "start_ns"])
def test_a_metadata_number_of_thousands_of_digits_is_damage_not_a_traceback(original, tmp_path, fact):
    """int() refuses more than 4,300 digits: every reader of such a record failed, record recover included."""
    rewrite(original, tmp_path / "run", metadata={"cellguard": {fact: "9" * 5000}})
    with open_record(tmp_path / "run") as rec:
        health = rec.health()
        assert len(rec.ticks(cycle=1)) == 1000 and rec.version == 2 and rec.epoch_wall_ns == _EPOCH
    assert not health.ok and "(5,002 characters)" in health.describe() and len(health.describe()) < 600
    recover(tmp_path / "run", tmp_path / "copy")
    with open_record(tmp_path / "copy") as rec:
        assert rec.health().facts is None


@pytest.mark.parametrize("metadata", [{"epoch_wall_ns": str(_EPOCH - _YEAR_NS)}, {"record_version": "0"},
                                      {"epoch_wall_ns": "99999999999999999999"}])
def test_a_metadata_epoch_other_than_the_contexts_reads_by_the_context(original, tmp_path, metadata):
    rewrite(original, tmp_path / "run", metadata={"cellguard": metadata})
    result = runner.invoke(app, ["record", "export", str(tmp_path / "run"), "--cycle", "1", "-o",
                                 str(tmp_path / "c.csv")])
    assert result.exit_code == 1, result.output
    assert "6000 rows" in result.output and "the context's values are used" in result.output
    with open_record(tmp_path / "run") as rec:
        health = rec.health()
    assert health.span_ns[1] < 5 * 10**9 and health.recoverable
    recover(tmp_path / "run", tmp_path / "copy")  # the copy states the context's values
    with open_record(tmp_path / "copy") as rec:
        assert rec.health().facts is None and rec.layout.metadata["cellguard"]["epoch_wall_ns"] == str(_EPOCH)


def _bad_rows(topic: str, d: dict) -> dict:
    if topic == "/cycles" and d["cycle"] == 2:
        d["cycle"] = 10**30
    if topic == "/events":
        d["t_ns"] = 10**30
    return d


def test_recover_leaves_out_index_rows_out_of_range(original, tmp_path):
    rewrite(original, tmp_path / "src", edit=_bad_rows)
    health = recover(tmp_path / "src", tmp_path / "out")
    assert health.off_schema == {"/cycles": 2, "/events": 1}  # cycle 2's begin and end markers, the event
    cycles = pq.read_table(tmp_path / "out" / "index" / "cycles").column("cycle").to_pylist()
    assert sorted(cycles) == [0, 1, 3] and pq.read_table(tmp_path / "out" / "index" / "events").num_rows == 0


@pytest.mark.parametrize("event", [{"cycle": "x"}, {"category": "zero"}, {"asked": "nan"}, {"joint": 5}])
def test_an_event_of_other_types_is_skipped(original, tmp_path, event):
    rewrite(original, tmp_path, edit=lambda topic, d: {**d, **event} if topic == "/events" else d)
    with open_record(tmp_path) as rec:
        assert list(rec.events()) == [] and rec.health().off_schema == {"/events": 1}


def test_a_failed_recovery_leaves_nothing(original, tmp_path, monkeypatch):
    def full_disk(record, folder):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(recovery, "_rebuild_index", full_disk)
    result = runner.invoke(app, ["record", "recover", str(original), "-o", str(tmp_path / "out")])
    assert "No space left on device" in one_error(result)
    assert os.listdir(tmp_path) == []


def test_a_recovery_into_a_mount_point_is_renamed_on_its_own_filesystem(original, tmp_path):
    """Staged beside the target, a mount point as -o failed with EXDEV and left index folders behind."""
    from run_copies import small_tmpfs

    with small_tmpfs(tmp_path / "mnt", "64m") as mnt:
        result = runner.invoke(app, ["record", "recover", str(original), "-o", str(mnt)])
        assert result.exit_code == 0, result.output
        assert sorted(os.listdir(mnt)) == ["index", "record.mcap"]
        with open_record(mnt) as rec:
            assert rec.health().ok


@pytest.mark.parametrize("context", [{"cell": 5}, {"embodiment": "x"}, {"policy": ["a"]}, {"record": []},
                                     {"servo_period_ns": "1000000"}, {"record": {"chunk_ns": "x"}},
                                     {"embodiment": {"calibration_dates": [1]}}])
def test_a_context_of_other_types_is_malformed(original, tmp_path, context):
    def edit(topic, d):
        if topic == "/context":
            d["context"] = {**d["context"], **context}
        return d

    rewrite(original, tmp_path / "run", edit=edit)
    result = runner.invoke(app, ["record", "info", str(tmp_path / "run")])
    assert result.exit_code == 1 and isinstance(result.exception, SystemExit), result.output
    assert "/context message(s) malformed" in result.output and "taken from the copy at the end" in result.output
    result = runner.invoke(app, ["record", "to-lerobot", str(tmp_path / "run"), "-o", str(tmp_path / "ds")])
    assert result.exit_code == 1, result.output
    assert "4 episodes" in result.output


def test_null_context_fields_read_as_absent(original, tmp_path):
    def edit(topic, d):
        if topic == "/context":
            d["context"] = {**d["context"], "cell": None, "embodiment": None}
        return d

    rewrite(original, tmp_path / "run", edit=edit)
    result = runner.invoke(app, ["record", "to-lerobot", str(tmp_path / "run"), "-o", str(tmp_path / "ds")])
    assert result.exit_code == 0, result.output
    tasks = pq.read_table(tmp_path / "ds" / "meta" / "tasks.parquet")
    assert tasks.column("__index_level_0__").to_pylist() == ["cycle"]


@pytest.mark.skipif(os.uname().sysname == "Darwin", reason="macOS file names are UTF-8")
def test_a_folder_name_that_is_not_utf8(original, tmp_path):
    folder = Path(os.fsdecode(os.fsencode(tmp_path) + b"/bad\xff"))
    recover(original, folder)
    with open_record(folder) as rec:
        assert len(rec.ticks(cycle=1)) == 1000  # the cycle's span from the index, opened by handle
    recover(folder, tmp_path / "copy")
    assert "bad\\xff" in open_record(tmp_path / "copy").layout.metadata["cellguard.recovered"]["source"]
    result = runner.invoke(app, ["record", "query", str(folder), "SELECT count(*) AS n FROM cycles"])
    assert "not UTF-8" in one_error(result)


def test_a_link_loop_is_named_as_the_record(tmp_path):
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "record.mcap").symlink_to(tmp_path / "run" / "x")
    (tmp_path / "run" / "x").symlink_to(tmp_path / "run" / "record.mcap")
    result = runner.invoke(app, ["record", "export", str(tmp_path / "run"), "-o", str(tmp_path / "t.csv")])
    assert one_error(result).startswith(f"error: {tmp_path / 'run'}: cannot be read")


def test_messages_are_read_a_chunk_at_a_time(original, monkeypatch):
    reads = []
    read_chunk = reader_module.read_chunk
    monkeypatch.setattr(reader_module, "read_chunk", lambda *a: reads.append(1) or read_chunk(*a))
    with open_record(original) as rec:
        rec.contexts  # noqa: B018
        reads.clear()
        next(rec.messages(["/ticks/decimated"]))
        assert len(reads) <= 2 < len(rec.layout.chunks)


def test_repeated_sequence_numbers_are_damage(original, tmp_path):
    rewrite(original, tmp_path, sequence=1)
    with open_record(tmp_path) as rec:
        health = rec.health()
    assert not health.ok and health.repeats["/ticks/decimated"] > 0
    assert "repeat a sequence number" in health.describe()


def test_an_index_copied_from_another_run_is_not_read_as_this_ones(original, tmp_path):
    record(tmp_path / "other", 4, 1500)  # same cycle numbers, other times
    shutil.copytree(original, tmp_path / "run")
    shutil.rmtree(tmp_path / "run" / "index")
    shutil.copytree(tmp_path / "other" / "index", tmp_path / "run" / "index")
    result = runner.invoke(app, ["record", "query", str(tmp_path / "run"), "SELECT count(*) AS n FROM cycles"])
    assert "an index copied from another run" in one_error(result)
    with open_record(tmp_path / "run") as rec:  # the cycle's span from the record's own markers
        assert rec.ticks(cycle=1).t_ns[0] == 1000 * 10**6


@pytest.mark.parametrize("command", [["record", "info"], ["diagnose"], ["record", "recover"]])
def test_a_context_stating_a_newer_format_is_refused_as_its_metadata_would_be(original, tmp_path, command):
    """The context is what the reader falls back on where the metadata record is lost: one stating a newer format was
    read with this version's rules (a full diagnosis), and recovered into a copy this version then refused."""
    def edit(topic, d):
        return {**d, "record_version": 99} if topic == "/context" else d

    rewrite(original, tmp_path / "run", edit=edit, metadata={"cellguard.context": {"record_version": "99"}})
    out = ["-o", str(tmp_path / "copy")] if command[-1] == "recover" else []
    line = one_error(runner.invoke(app, [*command, str(tmp_path / "run"), *out]))
    assert "record format version 99 is newer than this cellguard reads" in line
    assert not (tmp_path / "copy").exists()


def test_a_context_stating_a_newer_format_is_refused_at_every_read(original, tmp_path):
    """Refused once, the next read of the same Record found its contexts read (none) and went on: ticks and cycles
    of a format this version does not know."""
    def edit(topic, d):
        return {**d, "record_version": 99} if topic == "/context" else d

    rewrite(original, tmp_path / "run", edit=edit, metadata={"cellguard.context": {"record_version": "99"}})
    rec = reader_module.Record(tmp_path / "run" / "record.mcap", scan.scan(tmp_path / "run" / "record.mcap"))
    try:
        for read in (lambda: rec.contexts, lambda: rec.contexts, rec.ticks):
            with pytest.raises(reader_module.RecordError, match="record format version 99 is newer"):
                read()
    finally:
        rec.close()
