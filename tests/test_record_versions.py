"""Record format 2 against format 1: wall-clock log times, and the reader still reads format 1."""

from __future__ import annotations

import json

import numpy as np
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
from record_synth import DT_NS, JOINTS, context, record, values

from cellguard.record.index import connect
from cellguard.record.reader import open_record
from cellguard.record.schemas import CHANNELS, TICKS
from cellguard.record.writer import PROFILE, RECORD_VERSION

EPOCH = 1_790_000_000_000_000_000  # what record_synth states as the run's start


def test_format_2_logs_on_the_wall_clock_in_order_and_reads_on_the_run_clock(tmp_path):
    record(tmp_path, 4, 500, events={700: "position_clamp"})
    with open(tmp_path / "record.mcap", "rb") as f:
        times = [m.log_time for _, _, m in make_reader(f).iter_messages(log_time_order=False)]
    assert times == sorted(times) and times[0] == EPOCH  # the context at t = 0, in file order throughout
    with open_record(tmp_path) as rec:
        assert rec.version == RECORD_VERSION == 2 and rec.epoch_wall_ns == EPOCH and len(rec.record_id) == 32
        ticks = rec.ticks(cycle=1)
        assert ticks.t_ns[0] == 500 * DT_NS and rec.health().ok
        assert rec.health().span_ns[0] == 0
    rows = connect(tmp_path / "index").execute("SELECT DISTINCT site, cell_id FROM cycles").fetchall()
    assert rows == [("test-site", "cell-7")]


def test_a_format_1_record_still_reads(tmp_path):
    """Written as cellguard wrote it before format 2: log time = run clock, cellguard's channels only."""
    old = [c for c in CHANNELS if c.id <= 7]
    with open(tmp_path / "record.mcap", "wb") as f:
        writer = Writer(f, compression=CompressionType.ZSTD)
        writer.start(profile=PROFILE, library="cellguard")
        for c in old:
            schema = writer.register_schema(c.schema_name, c.schema_encoding, c.schema_text.encode())
            writer.register_channel(c.topic, c.message_encoding, schema)
        ctx = {"t_ns": 0, "epoch_wall_ns": EPOCH, "version": "v1", "changed": [], "versions": {}, "context": context()}
        writer.add_message(1, 0, json.dumps(ctx).encode(), 0, 1)
        writer.add_message(6, 0, json.dumps({"marker": "begin", "cycle": 0, "phase": "acceptance",
                                             "t_start_ns": 0}).encode(), 0, 1)
        batch = {"joints": JOINTS, "t_ns": np.arange(100) * DT_NS, "cycle": np.zeros(100, np.int32)}
        batch.update({k: np.stack([values(i)[k] for i in range(100)]) for k in values(0)})
        writer.add_message(2, 0, TICKS.encode(batch), 0, 1)
        end = {"marker": "end", "cycle": 0, "phase": "acceptance", "t_start_ns": 0, "t_end_ns": 99 * DT_NS,
               "success": True, "features": {"current_peak.elbow": 1.5}}
        writer.add_message(6, 99 * DT_NS, json.dumps(end).encode(), 99 * DT_NS, 2)
        writer.finish()
    with open_record(tmp_path) as rec:
        assert rec.context["site"] == "test-site"
        assert rec.version == 1 and rec.record_id is None and rec.epoch_wall_ns == EPOCH
        assert [c.features["current_peak.elbow"] for c in rec.cycles()] == [1.5]
        ticks = rec.ticks(cycle=0)
        np.testing.assert_array_equal(ticks.t_ns, np.arange(100) * DT_NS)
        assert rec.health().ok
