"""A record of format 1 (written before format 2: log time = run clock, no metadata, cellguard's channels only)
recovered: the copy reads as its source. It read as format 2 whose metadata was lost, its log times taken for the
wall clock: a span years before 1970, no ticks in any cycle."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
from record_synth import record
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.record.reader import open_record
from cellguard.record.schemas import BY_TOPIC
from cellguard.record.writer import PROFILE

runner = CliRunner()
FORMAT_2_ONLY = ("record_version", "record_id", "start_ns", "repeat")  # what a format-1 context did not state


def _as_format_1(source: Path, target: Path) -> None:
    """Rewrite the format-2 record of ``source`` as format 1 into ``target``: no metadata, the channels before the
    ROS 2 ones, times on the run clock, contexts without the format-2 facts."""
    target.mkdir()
    with open_record(source) as rec:
        epoch = rec.epoch_wall_ns
    with open(source / "record.mcap", "rb") as f, open(target / "record.mcap", "wb") as out:
        reader = make_reader(f)
        summary = reader.get_summary()
        writer = Writer(out, compression=CompressionType.ZSTD)
        writer.start(profile=PROFILE, library="cellguard")
        kept = {i: c for i, c in sorted(summary.channels.items()) if i < BY_TOPIC["/joint_states"].id}
        for i, c in kept.items():
            schema = summary.schemas[c.schema_id]
            writer.register_channel(c.topic, c.message_encoding,
                                    writer.register_schema(schema.name, schema.encoding, schema.data))
        for _, channel, m in reader.iter_messages(log_time_order=False):
            if m.channel_id in kept:
                data = m.data
                if channel.topic == "/context":
                    data = json.dumps({k: v for k, v in json.loads(data).items() if k not in FORMAT_2_ONLY}).encode()
                writer.add_message(m.channel_id, m.log_time - epoch, data, m.publish_time - epoch, m.sequence)
        writer.finish()


def _read(folder: Path, tmp_path: Path) -> dict:
    """What the CLI and reader say of ``folder``: format, id, span, cycles, events, one cycle's ticks exported."""
    csv = tmp_path / f"{folder.name}.csv"
    exported = runner.invoke(app, ["record", "export", str(folder), "--cycle", "2", "-o", str(csv)])
    assert exported.exit_code == 0, exported.output
    info = json.loads(runner.invoke(app, ["record", "info", str(folder), "--json"]).stdout)
    with open_record(folder) as rec:
        cycles = [(c.cycle, c.t_start_ns, c.t_end_ns, c.success) for c in rec.cycles()]
        events = [(e.t_ns, e.kind) for e in rec.events()]
    return {"format": info["record_version"], "id": info["record_id"], "span": info["span_s"],
            "start": info["start_utc"], "cycles": cycles, "events": events, "csv": csv.read_text()}


@pytest.fixture(scope="module")
def old(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("old")
    record(folder / "new", 4, 500, events={1200: "position_clamp"})
    _as_format_1(folder / "new", folder / "r1")
    return folder / "r1"


def test_a_recovered_format_1_record_reads_as_its_source(old, tmp_path):
    before = _read(old, tmp_path)
    assert before["format"] == 1 and before["span"][0] == 0 and len(before["cycles"]) == 4  # a sound format 1
    assert len(before["csv"].splitlines()) > 100 and before["events"]
    result = runner.invoke(app, ["record", "recover", str(old), "-o", str(tmp_path / "copy")])
    assert result.exit_code == 0, result.output
    assert _read(tmp_path / "copy", tmp_path) == before
    with open_record(tmp_path / "copy") as copy:
        assert "/joint_states" not in {c.topic for c in copy.layout.channels.values()}  # only what format 1 had
        assert copy.health().ok


def test_info_of_a_format_1_record_says_it_has_no_run_id(old):
    result = runner.invoke(app, ["record", "info", str(old)])
    assert result.exit_code == 0, result.output
    assert result.output.splitlines()[1].startswith("run      no run id  started ")
