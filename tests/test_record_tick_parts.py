"""``Record.tick_parts``: the ticks of ``ticks()`` a part at a time, by the same rules (``record export`` repeated the
reader's keep-first rule and its choice of joints with the reader's private helpers): ``ticks()`` is the
concatenation of the parts, where a copy of a tick in both streams or in two batches is kept once and a batch naming
other joints is skipped."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from record_synth import JOINTS, FullRateAltered, record, rewrite

from cellguard.errors import RecordError
from cellguard.record.reader import RATES, UnorderedTicks, open_record
from cellguard.record.schemas import TICK_FIELDS, TICKS

ROWS = 900  # values of a field a part: many parts of the synthetic record


@pytest.fixture(scope="module")
def overlapping(tmp_path_factory) -> Path:
    """6 cycles at 1 kHz, an event in cycle 2 (full rate from the start, overlapping the decimated stream); each
    full-rate batch's q_ref raised by 1000 times its number, batch 5 reaching half a batch back over batch 4, batch 7
    naming other joints."""
    out = tmp_path_factory.mktemp("rec")
    record(out / "source", 6, 1000, events={2500: "position_clamp"})
    edit = FullRateAltered(overlap_at=5, other_joints_at=7)
    rewrite(out / "source", out / "run", edit_bytes=edit)
    np.save(out / "overlap.npy", edit.overlap)
    return out / "run"


@pytest.mark.parametrize("rate", RATES)
def test_the_ticks_are_the_parts_joined(overlapping, rate):
    with open_record(overlapping) as rec:
        parts = list(rec.tick_parts(rate, ROWS))
        health = rec.health()
    with open_record(overlapping) as rec:
        whole = rec.ticks(rate=rate)
        assert rec.health() == health
    assert len(parts) > 1 and max(len(p) for p in parts) * len(JOINTS) <= ROWS + 100 * len(JOINTS)
    assert all(p.joints == whole.joints == JOINTS for p in parts)
    for name in ("t_ns", "cycle", *TICK_FIELDS):
        assert np.array_equal(np.concatenate([getattr(p, name) for p in parts]), getattr(whole, name)), name
    assert health.off_schema == {"/ticks/full": 1}
    if rate == "all":  # the decimated copy of a tick, else the one read first (batch 4's, not 5's)
        with open_record(overlapping) as rec:
            decimated = rec.ticks(rate="decimated").t_ns
        overlap = np.isin(whole.t_ns, np.load(overlapping.parent / "overlap.npy")) & ~np.isin(whole.t_ns, decimated)
        assert np.all(np.abs(whole.q_ref[np.isin(whole.t_ns, decimated)]) < 500)
        assert overlap.any() and np.all((whole.q_ref[overlap] > 3500) & (whole.q_ref[overlap] < 4500))


def test_a_batch_reaching_back_before_a_part_handed_on_is_refused_and_ticks_reads_it_whole(overlapping, tmp_path):
    seen = {"n": 0}

    def back(topic: str, data: bytes) -> bytes:
        if topic == "/ticks/decimated" and (seen.__setitem__("n", seen["n"] + 1) or seen["n"] == 50):
            d = TICKS.decode(data)
            return TICKS.encode({**d, "t_ns": d["t_ns"] - 4_000_000_000 + 7})
        return data

    rewrite(overlapping, tmp_path, edit_bytes=back)
    with open_record(tmp_path) as rec:
        with pytest.raises(UnorderedTicks, match="/ticks/decimated batch reaches back"):
            list(rec.tick_parts("all", ROWS))
        ticks = rec.ticks()
    assert len(np.unique(ticks.t_ns)) == len(ticks) and np.all(np.diff(ticks.t_ns) > 0)


def test_an_unknown_rate_is_refused(overlapping):
    with open_record(overlapping) as rec, pytest.raises(RecordError, match="rate: 'bogus' is not one of"):
        next(rec.tick_parts("bogus", ROWS))


def test_a_record_without_ticks_gives_one_empty_part(overlapping, tmp_path):
    rewrite(overlapping, tmp_path, edit_bytes=lambda topic, data: b"" if topic.startswith("/ticks/") else data)
    with open_record(tmp_path) as rec:
        parts = list(rec.tick_parts("all", ROWS))
    assert len(parts) == 1 and len(parts[0]) == 0 and parts[0].q_ref.shape == (0, 0)
