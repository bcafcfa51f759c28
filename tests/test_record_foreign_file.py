"""An MCAP file of another tool (no cellguard channel) is one error line naming it and its topics, exit 2, in every
command that reads a record: it read as a damaged cellguard record ("10 /context message(s) malformed", "record format
1"), `record export` wrote a 0-row csv, and `record recover` exited 0 with its messages filed under /context."""

from __future__ import annotations

from pathlib import Path

import pytest
from mcap.writer import Writer
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import RecordError
from cellguard.record.reader import open_record
from cellguard.record.scan import scan

runner = CliRunner()
LINE = "not a cellguard record (no cellguard channel; its topics: /foo)"


def foreign(folder: Path, chunk_size: int = 1 << 20, topics: tuple[str, ...] = ("/foo",),
            schema_name: str | None = "other.Message") -> Path:
    """``folder/record.mcap``: a channel of each of ``topics`` (the first id 1, as /context's), another tool's schema
    (None: none, id 0, as MCAP allows for JSON), ten messages each, written by mcap's Writer."""
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / "record.mcap", "wb") as f:
        writer = Writer(f, chunk_size=chunk_size)
        writer.start(profile="", library="other tool")
        schema = 0 if schema_name is None else writer.register_schema(schema_name, "jsonschema", b"{}")
        channels = [writer.register_channel(topic, "json", schema) for topic in topics]
        for i in range(10):
            for channel in channels:
                writer.add_message(channel, i * 1000, b'{"t_ns": 0}', i * 1000)
        writer.finish()
    return folder


@pytest.mark.parametrize("args", [["record", "info"], ["record", "export", "-o", "{out}/x.csv"],
                                  ["record", "recover", "-o", "{out}/copy"], ["record", "to-lerobot", "-o", "{out}/lr"],
                                  ["record", "query", "{run}", "SELECT 1"], ["diagnose"],
                                  ["report", "-o", "{out}/r.html"]])
@pytest.mark.parametrize("as_file", [False, True])
def test_every_reader_command_says_it_is_not_a_cellguard_record(tmp_path, args, as_file):
    run = foreign(tmp_path / "run")
    (tmp_path / "out").mkdir()
    target = str(run / "record.mcap" if as_file else run)
    args = [a.format(out=tmp_path / "out", run=target) for a in args]
    argv = args if "query" in args else [*args[:2], target, *args[2:]] if args[0] == "record" else [args[0], target,
                                                                                                    *args[1:]]
    result = runner.invoke(app, argv)
    assert result.exit_code == 2, result.output
    assert result.output.strip().splitlines() == [f"error: {run / 'record.mcap'}: {LINE}"]
    assert not any((tmp_path / "out").iterdir())  # nothing written


def test_a_foreign_file_without_its_summary_is_refused_by_its_channel_records(tmp_path):
    """A crash-cut foreign file: the channel records in its chunks say what it is."""
    data = (foreign(tmp_path / "whole", chunk_size=64) / "record.mcap").read_bytes()
    last = scan(tmp_path / "whole" / "record.mcap").chunks[-1]
    (tmp_path / "cut").mkdir()
    (tmp_path / "cut" / "record.mcap").write_bytes(data[:last.offset + last.length])
    with pytest.raises(RecordError, match=LINE.replace("(", r"\(").replace(")", r"\)")):
        open_record(tmp_path / "cut")


@pytest.mark.parametrize("schema_name", ["other.Message", None, "cellguardian.Foo"])
def test_a_foreign_file_with_a_context_topic_of_its_own_is_no_cellguard_record(tmp_path, schema_name):
    """Another tool's /context (its own schema, or none) beside its /camera: the topic's name alone made it a damaged
    cellguard record, "5 /context message(s) malformed", and `record recover` wrote a copy."""
    run = foreign(tmp_path / "run", topics=("/context", "/camera"), schema_name=schema_name)
    with pytest.raises(RecordError, match=r"not a cellguard record \(no cellguard channel; its topics: /camera, "
                                          r"/context\)"):
        open_record(run)
