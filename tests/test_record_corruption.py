"""Truncated and bit-flipped records: what is read is right, what is lost is reported, recovery finishes the file."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from record_synth import DT_NS, record, values

from cellguard.errors import RecordError
from cellguard.record.reader import open_record
from cellguard.record.recovery import recover
from cellguard.record.writer import RecordConfig


@pytest.fixture(scope="module")
def original(tmp_path_factory) -> bytes:
    out = tmp_path_factory.mktemp("orig")
    record(out, 4, 1500, events={2500: "position_clamp"}, config=RecordConfig(pre_trigger_s=1.0, post_trigger_s=0.5))
    return (out / "record.mcap").read_bytes()


def _check_values(ticks) -> None:
    k = (ticks.t_ns // DT_NS).astype(int)
    if not len(k):  # cut before the first tick chunk: nothing to compare
        return
    for name in ("q_ref", "q_cmd", "q_meas", "qd_meas", "effort", "current"):
        np.testing.assert_array_equal(getattr(ticks, name), np.stack([values(i)[name] for i in k]).reshape(-1, 6))


def _read(path):
    """Open, read everything, return (ticks, health); None when nothing at all is readable."""
    try:
        with open_record(path) as rec:
            return rec.ticks(), rec.health()
    except RecordError:
        return None


def test_make_reader_refuses_a_truncated_file_but_the_linear_scan_recovers(original, tmp_path):
    path = tmp_path / "cut.mcap"
    path.write_bytes(original[: len(original) * 2 // 3])
    with open(path, "rb") as f, pytest.raises(Exception):
        list(make_reader(f).iter_messages())
    ticks, health = _read(path)
    assert len(ticks) > 100 and health.truncated and not health.ok
    _check_values(ticks)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(fraction=st.floats(0.0, 1.0, exclude_max=True))
def test_random_truncation(original, tmp_path, fraction):
    path = tmp_path / "cut.mcap"
    path.write_bytes(original[: int(len(original) * fraction)])
    result = _read(path)
    if result is None:
        return  # nothing complete yet: refused, never a false success
    ticks, health = result
    assert not health.ok
    _check_values(ticks)
    with open_record(path) as rec:
        k = rec.ticks(rate="decimated").t_ns // DT_NS
    np.testing.assert_array_equal(k, np.arange(0, 20 * len(k), 20))  # a prefix of the run, no holes


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(flips=st.lists(st.tuples(st.floats(0.0, 1.0, exclude_max=True), st.integers(0, 7)), min_size=1, max_size=4))
def test_random_bit_flips(original, tmp_path, flips):
    data = bytearray(original)
    for where, bit in flips:
        data[int(where * len(data))] ^= 1 << bit
    path = tmp_path / "flipped.mcap"
    path.write_bytes(bytes(data))
    result = _read(path)
    if result is None:
        return
    ticks, health = result
    _check_values(ticks)  # a damaged chunk is skipped, never read as wrong numbers
    reference = _read_bytes(original, tmp_path)
    if len(ticks) < len(reference):
        assert not health.ok  # something was lost, and it says so


def _read_bytes(data: bytes, tmp_path):
    path = tmp_path / "ref.mcap"
    path.write_bytes(data)
    return _read(path)[0]


def test_a_damaged_chunk_is_skipped_and_reading_goes_on(original, tmp_path):
    data = bytearray(original)
    data[len(data) // 3] ^= 0xFF
    path = tmp_path / "hole.mcap"
    path.write_bytes(bytes(data))
    ticks, health = _read(path)
    full = _read_bytes(original, tmp_path)
    assert 0 < len(ticks) < len(full)
    assert ticks.t_ns[-1] == full.t_ns[-1]  # read past the hole to the end
    assert health.chunks_damaged >= 1 and any(health.gaps.values())
    _check_values(ticks)


def test_recover_writes_a_finished_file_that_make_reader_opens(original, tmp_path):
    source = tmp_path / "src"
    source.mkdir()
    (source / "record.mcap").write_bytes(original[: len(original) // 2])
    with open_record(source) as rec:
        before = rec.ticks()
    recover(source, tmp_path / "fixed")
    with open(tmp_path / "fixed" / "record.mcap", "rb") as f:
        reader = make_reader(f)
        assert reader.get_summary().statistics.message_count > 0
        assert len(list(reader.iter_messages())) == reader.get_summary().statistics.message_count
    with open_record(tmp_path / "fixed") as rec:
        after = rec.ticks()
        assert rec.health().finished
        cycles = list(rec.cycles())
    np.testing.assert_array_equal(before.t_ns, after.t_ns)
    np.testing.assert_array_equal(before.q_meas, after.q_meas)
    assert (tmp_path / "fixed" / "index" / "cycles").is_dir() == bool(cycles)


def test_recover_refuses_to_overwrite_its_source(original, tmp_path):
    (tmp_path / "record.mcap").write_bytes(original)
    with pytest.raises(RecordError, match="overwrite"):
        recover(tmp_path, tmp_path)


@pytest.mark.parametrize("content", [b"", b"not an mcap file at all" * 10])
def test_an_unreadable_file_is_an_error_not_an_empty_success(tmp_path, content):
    (tmp_path / "record.mcap").write_bytes(content)
    with pytest.raises(RecordError):
        open_record(tmp_path)


def test_a_record_whose_start_is_lost_still_knows_its_format_id_epoch_and_clock(original, tmp_path):
    """The metadata record and the first chunk zeroed: the record read as format 1 with no id, started 'None',
    and spans in wall-clock seconds since 1970; the context copy at the end now states them."""
    data = bytearray(original)
    data[40:6040] = bytes(6000)
    (tmp_path / "record.mcap").write_bytes(bytes(data))
    with open_record(tmp_path) as damaged:
        health = damaged.health()
        stated = (damaged.version, damaged.record_id, damaged.epoch_wall_ns, damaged.start_ns)
    assert damaged.context_loss is not None  # the first context was in the zeroed bytes
    (tmp_path / "whole").mkdir()
    (tmp_path / "whole" / "record.mcap").write_bytes(original)
    with open_record(tmp_path / "whole") as whole:
        assert stated == (whole.version, whole.record_id, whole.epoch_wall_ns, whole.start_ns) and stated[0] == 2
    assert 0 <= health.span_ns[0] < health.span_ns[1] < 10**12  # the record's clock, not ns since 1970
