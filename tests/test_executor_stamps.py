"""Executor: a chunk's stamp outside +-2**62 ns is a refused chunk (an event), never an exception on the servo path."""

from __future__ import annotations

import numpy as np
import pytest

from cellguard.control.executor import Executor
from cellguard.policy.chunk import ActionChunk
from cellguard.robot.registry import make_cell

PROFILE = make_cell("arm-pick-place").profile
Q0 = np.array([0.0, -0.3, 1.9, 1.55, 0.0, 0.025])
MS = 1_000_000


def _chunk(t_obs_ns, offset: float = 0.0) -> ActionChunk:
    return ActionChunk(np.tile(Q0 + offset * (np.arange(6) < 5), (10, 1)), t_obs_ns, 20 * MS)


@pytest.mark.parametrize("stamp", [2**62 + 1, 2**63 - 1, 2**63, 2**70, np.uint64(2**63), np.int64(2**63 - 1),
                                   -(2**62) - 1, -(2**63), np.int64(-(2**63)), True])
def test_a_stamp_beyond_2_62_is_a_rejected_chunk_and_the_next_is_taken(stamp):
    ex = Executor(PROFILE, Q0, MS)
    events = ex.push(_chunk(stamp), MS)
    assert [e.kind for e in events] == ["chunk_rejected"] and "t_obs_ns" in events[0].reason
    assert np.array_equal(ex.reference(2 * MS), Q0)
    assert ex.push(_chunk(2 * MS, 0.01), 3 * MS) == []  # nothing of the refused one stays behind


@pytest.mark.parametrize("stamp, in_use, kinds", [
    (2**62, False, []),
    (2**62, True, []),
    (-(2**62), False, ["chunk_stale"]),
    (-(2**62), True, ["chunk_rejected"]),  # out of order: older than the chunk in use
])
def test_a_stamp_at_2_62_is_taken_without_an_exception(stamp, in_use, kinds):
    """The bound's edge goes through placing, the blend from rest or from a curve, and the ticks after it (on a
    clock that has reached the stamp: one ahead of the tick is refused, below)."""
    ex, now = Executor(PROFILE, Q0, MS), max(stamp, 0) + MS
    if in_use:
        ex.push(_chunk(now - 2 * MS, 0.01), now - 2 * MS)
        ex.reference(now - 2 * MS)
    assert [e.kind for e in ex.push(_chunk(stamp), now)] == kinds
    assert all(np.isfinite(ex.reference(now + t * MS)).all() for t in range(1, 300))


@pytest.mark.parametrize("ahead_ns", [MS + 1, 20 * MS, 100 * 10**9, 2**62 - 5 * MS])
def test_a_chunk_stamped_after_its_tick_is_refused_and_the_next_on_time_is_taken(ahead_ns):
    """A policy or bridge on another clock: taken, a chunk answering a future observation blocked every later
    chunk as out of order, until the watchdog stopped the run."""
    ex = Executor(PROFILE, Q0, MS)
    ex.push(_chunk(0, 0.01), 0)
    events = ex.push(_chunk(5 * MS + ahead_ns, 0.03), 5 * MS)
    assert [e.kind for e in events] == ["chunk_rejected"] and "after this tick" in events[0].reason
    assert ex.push(_chunk(6 * MS, 0.02), 7 * MS) == []
    q = [ex.reference(t * MS) for t in range(7, 600)][-1]
    assert np.allclose(q[:5], Q0[:5] + 0.02)


def test_a_chunk_stamped_up_to_one_period_after_its_tick_is_taken():
    """A bridge's read stamped within the tick it is used on."""
    ex = Executor(PROFILE, Q0, MS)
    assert ex.push(_chunk(2 * MS, 0.01), MS) == []
