"""RecordConfig takes only finite numbers in their ranges: the pre-trigger ring is sized from them before the first
tick (``pre_trigger_s`` inf overflowed there, 1e5 s asked 13.4 GiB, and either left an empty record.mcap)."""

from __future__ import annotations

import io
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from record_synth import DT_NS, JOINTS, context

from cellguard.errors import RecordError
from cellguard.record.writer import MAX_CHUNK_NS, MAX_WINDOW_S, MIN_DECIMATED_HZ, RecordConfig, Recorder

NUMERIC = ("chunk_ns", "fsync_ns", "decimated_hz", "pre_trigger_s", "post_trigger_s", "index_part_rows",
           "context_every_s")
# at 1 kHz, the fastest servo rate a run drives, with the arm's 6 joints: 350 s of ticks at most (the window, four
# chunks, one decimated period) and the session's 2 s queue, 156 bytes a tick
RING_BUDGET_BYTES = 55_000_000


def _config(field: str, value) -> RecordConfig:
    """``field`` set to ``value``; a chunk_ns alone varied gets an fsync_ns it cannot fall short of."""
    return RecordConfig(**{field: value, **({"fsync_ns": MAX_CHUNK_NS} if field == "chunk_ns" else {})})


def _ring_bytes(config: RecordConfig) -> int:
    """The shared ring a run's recording makes for ``config`` on the arm at 1 kHz (a 2 s queue)."""
    ring = Recorder(io.BytesIO(), joints=JOINTS, dt_ns=DT_NS, context=context(record=config.to_dict()),
                    config=config, slack=round(2e9 / DT_NS)).ring
    return ring.t_ns.nbytes + ring.cycle.nbytes + ring.values.nbytes


@pytest.mark.parametrize("field, value", [
    ("pre_trigger_s", math.inf), ("pre_trigger_s", 1e5), ("pre_trigger_s", MAX_WINDOW_S * 1.001),
    ("post_trigger_s", math.inf), ("post_trigger_s", 1e308), ("decimated_hz", math.inf), ("decimated_hz", 1e-300),
    ("decimated_hz", math.nan), ("decimated_hz", 1e9), ("context_every_s", math.inf), ("chunk_ns", 10**30), ("chunk_ns", 1.5e8),
    ("fsync_ns", 2e9), ("index_part_rows", 2.5), ("pre_trigger_s", True), ("context_every_s", "60")])
def test_a_value_out_of_range_or_not_a_number_is_refused_naming_the_field(field, value):
    with pytest.raises(RecordError, match=rf"^record config {field}: .* is not allowed: give "):
        _config(field, value)


def test_the_window_limit_is_named_with_its_reason():
    with pytest.raises(RecordError) as refused:
        RecordConfig(pre_trigger_s=math.inf)
    assert str(refused.value) == ("record config pre_trigger_s: inf is not allowed: give a finite number of seconds "
                                  "from 0 to MAX_WINDOW_S (300 s): the pre-trigger ring keeps that much at the servo "
                                  "rate in memory")


def test_every_limit_at_once_still_fits_the_ring_budget():
    worst = RecordConfig(chunk_ns=MAX_CHUNK_NS, fsync_ns=MAX_CHUNK_NS, decimated_hz=MIN_DECIMATED_HZ,
                         pre_trigger_s=MAX_WINDOW_S, post_trigger_s=MAX_WINDOW_S)
    assert RING_BUDGET_BYTES * 0.95 < _ring_bytes(worst) <= RING_BUDGET_BYTES


@settings(max_examples=300, deadline=None)
@given(field=st.sampled_from(NUMERIC),
       value=st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-2**80, 2**80)))
def test_any_number_makes_a_config_whose_ring_fits_or_is_refused_naming_its_field(field, value):
    try:
        config = _config(field, value)
    except RecordError as refused:
        assert str(refused).startswith(f"record config {field}: {value!r} is not allowed")
        return
    assert _ring_bytes(config) <= RING_BUDGET_BYTES
