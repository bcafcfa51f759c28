"""A record whose channel ids are not the recorder's (rewritten without loss by mcap's own Writer, channels numbered
in another order, some left out) reads as its source, and so does its `record recover` copy: the copy filed every
message under the channel of the source's id, another topic there (0 cycles), and the reader gave a topic the file
lacks cellguard's fixed id, another topic's in that file."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
from record_synth import record

from cellguard.record.reader import open_record
from cellguard.record.recovery import recover
from cellguard.record.schemas import CHANNELS
from cellguard.record.scan import scan

TOPICS = [c.topic for c in CHANNELS]
OPTIONAL = TOPICS[1:]  # all but /context: a record without it is no cellguard record


@pytest.fixture(scope="module")
def source(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("source")
    record(folder, 4, 300, events={100: "position_clamp", 700: "velocity_limit"}, failed={3})
    return folder


def remux(source: Path, target: Path, order: list[str], chunk_size: int = 1 << 20) -> None:
    """``source``'s record rewritten by mcap's Writer into ``target``, its channels of ``order`` only, registered
    (so numbered) in that order; every message of them copied as it is."""
    target.parent.mkdir(parents=True, exist_ok=True)
    with open(source / "record.mcap", "rb") as f, open(target, "wb") as out:
        reader = make_reader(f)
        summary = reader.get_summary()
        writer = Writer(out, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        writer.start(profile="ros2", library="remux")
        for m in reader.iter_metadata():
            writer.add_metadata(m.name, m.metadata)
        by_topic = {c.topic: c for c in summary.channels.values()}
        ids = {}
        for topic in order:
            c = by_topic[topic]
            s = summary.schemas[c.schema_id]
            schema = writer.register_schema(s.name, s.encoding, s.data)
            ids[c.id] = writer.register_channel(topic, c.message_encoding, schema, c.metadata)
        for _, channel, m in reader.iter_messages(log_time_order=False):
            if channel.id in ids:
                writer.add_message(ids[channel.id], m.log_time, m.data, m.publish_time, m.sequence)
        writer.finish()


def read(path: Path) -> tuple:
    """What a reader takes from the record at ``path``: cycles, events, ticks of every rate, health."""
    with open_record(path) as rec:
        ticks = [rec.ticks(rate=rate) for rate in ("decimated", "full")]
        return (list(rec.cycles()), list(rec.events()), [(t.t_ns, t.q_meas, t.cycle) for t in ticks], rec.health())


def same_ticks(got: list, expected: list) -> bool:
    """Each rate's ticks as expected; None: none."""
    return all(len(g[0]) == 0 if e is None else all(map(np.array_equal, g, e)) for g, e in zip(got, expected))


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(order=st.permutations(OPTIONAL), keep=st.lists(st.booleans(), min_size=len(OPTIONAL),
                                                        max_size=len(OPTIONAL)), at=st.integers(0, len(OPTIONAL)))
def test_any_numbering_and_subset_reads_and_recovers_as_the_source(source, order, keep, at):
    """Any permutation of the ids (/context anywhere among them), any subset of the other channels."""
    kept = [topic for topic, k in zip(order, keep) if k]
    kept.insert(min(at, len(kept)), "/context")
    cycles, events, ticks, _ = read(source)
    with tempfile.TemporaryDirectory() as tmp:
        remuxed = Path(tmp) / "remux" / "record.mcap"
        remux(source, remuxed, kept)
        recover(remuxed.parent, Path(tmp) / "copy")
        for path in (remuxed, Path(tmp) / "copy"):
            got_cycles, got_events, got_ticks, health = read(path)
            assert health.ok, health.describe()
            assert got_cycles == (cycles if "/cycles" in kept else [])
            assert got_events == (events if "/events" in kept else [])
            assert same_ticks(got_ticks, [t if f"/ticks/{rate}" in kept else None
                                          for t, rate in zip(ticks, ("decimated", "full"))])


def test_a_remuxed_record_without_its_summary_reads_by_the_channel_records_in_its_chunks(source, tmp_path):
    """A crash: no summary, so the channel records the chunks hold say the ids (small chunks: spread over many)."""
    order = TOPICS[::-1]  # /context last: id 13
    remux(source, tmp_path / "r" / "record.mcap", order, chunk_size=4096)
    data = (tmp_path / "r" / "record.mcap").read_bytes()
    last = scan(tmp_path / "r" / "record.mcap").chunks[-1]
    (tmp_path / "cut").mkdir()
    (tmp_path / "cut" / "record.mcap").write_bytes(data[:last.offset + last.length])  # every chunk, no summary
    assert not scan(tmp_path / "cut" / "record.mcap").finished
    cycles, events, ticks, _ = read(source)
    for path in (tmp_path / "cut", tmp_path / "copy"):
        if path.name == "copy":
            recover(tmp_path / "cut", path)
        got_cycles, got_events, got_ticks, health = read(path)
        assert (got_cycles, got_events) == (cycles, events) and same_ticks(got_ticks, ticks)
        assert not any(health.off_schema.values()), health.describe()
