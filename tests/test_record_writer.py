"""The recorder writes what the reader reads back: ticks at two rates, events, cycles, context."""

from __future__ import annotations

import datetime as dt
import json
import time

import numpy as np
import pytest
from mcap.reader import make_reader
from record_synth import DT_NS, JOINTS, context, record, values

from cellguard.errors import RecordError
from cellguard.record.index import connect
from cellguard.record.reader import open_record
from cellguard.record.writer import RecordConfig, Recorder

CONFIG = RecordConfig(pre_trigger_s=1.0, post_trigger_s=0.5)


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    out = tmp_path_factory.mktemp("rec")
    # 6 cycles of 2 s; an envelope event in cycle 3 at t = 7.0 s, a routine one at 2.5 s; cycle 5 fails
    record(out, 6, 2000, events={7000: "position_clamp", 2500: "chunk_steps_dropped"}, config=CONFIG, failed={5})
    return out


def _expected(ticks) -> dict:
    k = (ticks.t_ns // DT_NS).astype(int)
    return {name: np.stack([values(i)[name] for i in k]) for name in values(0)}


def test_decimated_stream_is_continuous_at_50_hz_with_exact_values(folder):
    with open_record(folder) as rec:
        ticks = rec.ticks(rate="decimated")
    assert len(ticks) == 6 * 2000 // 20
    assert set(np.diff(ticks.t_ns)) == {20 * DT_NS}
    for name, want in _expected(ticks).items():
        np.testing.assert_array_equal(getattr(ticks, name), want, err_msg=name)
    np.testing.assert_array_equal(ticks.cycle, ticks.t_ns // (2000 * DT_NS))


def test_full_rate_window_around_an_event_and_a_failed_cycle(folder):
    with open_record(folder) as rec:
        full = rec.ticks(rate="full")
    t = full.t_ns
    assert set(np.diff(t)) <= {DT_NS} | {int(x) for x in np.diff(t) if x > DT_NS}  # sorted, unique
    in_window = lambda a, b: np.count_nonzero((t >= a * 1e9) & (t < b * 1e9))  # noqa: E731
    assert in_window(6.0, 7.5) == 1500  # 1 s before the event, 0.5 s after: every tick
    assert in_window(1.0, 4.0) == 0  # the routine event opened no window
    assert in_window(11.0, 12.0) == 1000  # the failed cycle's last second
    assert len(t) < 6000


def test_cycles_events_and_context_read_back(folder):
    with open_record(folder) as rec:
        cycles = list(rec.cycles())
        events = list(rec.events())
        assert rec.context["site"] == "test-site"
        assert rec.epoch_wall_ns == 1_790_000_000_000_000_000
    assert [c.cycle for c in cycles] == list(range(6))
    assert [c.success for c in cycles] == [True] * 5 + [False]
    assert cycles[3].t_start_ns == 6_000_000_000 and cycles[3].t_end_ns == 8_000_000_000
    assert cycles[4].features["current_peak.elbow"] == 4.0
    assert {c.phase for c in cycles[:3]} == {"acceptance"}
    assert [(e.t_ns, e.kind, e.joint, e.asked, e.sent, e.cycle) for e in events] == [
        (2_500_000_000, "chunk_steps_dropped", "elbow", 1.0, 0.5, 1),
        (7_000_000_000, "position_clamp", "elbow", 1.0, 0.5, 3)]


def test_one_cycle_of_ticks_merges_both_rates(folder):
    with open_record(folder) as rec:
        inside = rec.ticks(cycle=3)
        outside = rec.ticks(cycle=1)
    assert len(outside) == 100 and set(outside.cycle) == {1}
    assert set(inside.cycle) == {3}
    assert inside.t_ns[0] == 6_000_000_000 and len(inside) > 1500


def test_sequence_numbers_are_monotonic_without_gaps(folder):
    with open(folder / "record.mcap", "rb") as f:
        seqs = {}
        for _, channel, message in make_reader(f).iter_messages(log_time_order=False):
            seqs.setdefault(channel.topic, []).append(message.sequence)
    for topic, seq in seqs.items():
        assert seq == list(range(1, len(seq) + 1)), topic
    with open_record(folder) as rec:
        assert rec.health().ok


def test_index_rows_carry_versions_and_match_the_record(folder):
    con = connect(folder / "index")
    rows = con.execute('SELECT cycle, success, "current_peak.elbow", policy_version, day '
                       'FROM cycles ORDER BY cycle').fetchall()
    assert [r[0] for r in rows] == list(range(6))
    assert [r[2] for r in rows] == [float(c) for c in range(6)]
    assert rows[5][1] is False and len({r[3] for r in rows}) == 1 and len(rows[0][3]) == 12
    assert str(rows[0][4]).startswith("2026-")
    kinds = con.execute("SELECT kind FROM events ORDER BY t_ns").fetchall()
    assert kinds == [("chunk_steps_dropped",), ("position_clamp",)]


def test_a_context_change_mid_run_is_recorded(tmp_path):
    rec = Recorder.create(tmp_path, joints=JOINTS, dt_ns=DT_NS, context=context())
    rec.set_context(context(), 5)  # unchanged: nothing written
    rec.set_context(context(fixture_datum=[0.304, 0.1, 0.0]), 10)
    rec.close()
    with open_record(tmp_path) as r:
        changes = r.contexts
    assert [c.t_ns for c in changes] == [0, 10]
    assert changes[1].changed == ("fixture_datum",)
    assert changes[0].versions["datum_version"] != changes[1].versions["datum_version"]
    assert changes[0].versions["policy_version"] == changes[1].versions["policy_version"]


def test_every_channel_declares_its_schema(folder):
    with open(folder / "record.mcap", "rb") as f:
        summary = make_reader(f).get_summary()
    assert {c.topic for c in summary.channels.values()} == {
        "/context", "/ticks/decimated", "/ticks/full", "/chunks", "/events", "/cycles", "/measurements",
        "/joint_states", "/joint_states/full", "/tf", "/tf_static", "/robot_description", "/events/log"}
    for channel in summary.channels.values():
        schema = summary.schemas[channel.schema_id]
        assert schema.encoding in ("jsonschema", "ros2msg") and schema.data
        if schema.encoding == "jsonschema":
            assert json.loads(schema.data)["type"] == "object"


@pytest.mark.parametrize("field, value",
                         [("chunk_ns", 0), ("fsync_ns", 1), ("decimated_hz", 0.0), ("pre_trigger_s", -1.0)])
def test_bad_config_names_the_field(field, value):
    with pytest.raises(RecordError, match=field):
        RecordConfig(**{field: value})


def test_a_chunk_read_for_some_channels_holds_exactly_their_messages_of_a_full_read(tmp_path):
    """The reader's lean path (messages of the wanted channels only, the rest skipped undecoded) gives
    the same messages, in the same order, as decoding every record of the chunk with the mcap package."""
    from mcap.records import Message

    from cellguard.record.scan import read_chunk

    record(tmp_path, cycles=6, ticks_per_cycle=150, events={40: "clamp", 700: "clamp"})
    with open_record(tmp_path) as rec:
        ids = {c.topic: c.id for c in rec.layout.channels.values()}
        for topics in (["/cycles"], ["/events", "/cycles"], list(ids)):
            wanted = {ids[t] for t in topics if t in ids}
            for ref in rec.layout.chunks:
                full = [m for m in read_chunk(rec._buf, ref) if isinstance(m, Message) and m.channel_id in wanted]
                assert read_chunk(rec._buf, ref, wanted) == full
        assert len(list(rec.cycles())) == 6 and len(list(rec.events())) == 2


def test_a_record_on_a_clock_counted_from_boot_is_stamped_at_the_real_time(tmp_path):
    """Wall time reads the monotonic clock, counted from boot: the record took the start as the clock's zero, so
    every message showed late by the host's uptime (30 days here) and the index's dates were that far off."""
    from cellguard.cli import app
    from cellguard.robot.state import State
    from typer.testing import CliRunner

    boot = 30 * 24 * 3600 * 10**9  # the run clock when the run starts: the host has been up 30 days
    began = time.time_ns()
    rec = Recorder.create(tmp_path, joints=JOINTS, dt_ns=DT_NS, context=context(), start_ns=boot)
    rec.cycle_begin(0, "acceptance", boot)
    for k in range(200):
        v = values(k)
        rec.tick(0, v["q_ref"], v["q_cmd"], State(boot + k * DT_NS, v["q_meas"], v["qd_meas"], v["effort"], v["current"]))
    rec.cycle_end({"cycle": 0, "phase": "acceptance", "success": True, "features": {}}, boot + 200 * DT_NS)
    rec.close()
    with open(tmp_path / "record.mcap", "rb") as f:
        log_times = [m.log_time for _, _, m in make_reader(f).iter_messages()]
    assert began - 10**9 < min(log_times) and max(log_times) < time.time_ns() + 10**9  # now, not 30 days on
    with open_record(tmp_path) as r:
        assert r.context_loss is None and r.contexts[0].t_ns == boot == r.start_ns
        assert abs(r.start_wall_ns - began) < 10**9
    info = json.loads(CliRunner().invoke(app, ["record", "info", str(tmp_path), "--json"]).stdout)
    assert info["start_utc"][:10] == dt.datetime.fromtimestamp(began * 1e-9, dt.timezone.utc).date().isoformat()
    assert str(connect(tmp_path / "index").execute("SELECT day FROM cycles").fetchone()[0]) == info["start_utc"][:10]
