"""Executor: validation at the edge, stale steps dropped, stitching continuous in position and velocity."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cellguard.control.executor import Executor
from cellguard.policy.chunk import ActionChunk
from cellguard.robot.registry import make_cell

PROFILE = make_cell("arm-pick-place").profile
Q0 = np.array([0.0, -0.3, 1.9, 1.55, 0.0, 0.025])
MS = 1_000_000


def _wave(t_s: np.ndarray, phase: float = 0.0) -> np.ndarray:
    t = np.asarray(t_s)[:, None]
    return Q0 + 0.2 * np.sin(2.0 * t + phase) * (np.arange(6) < 5) + 0.002 * np.sin(3.0 * t) * (np.arange(6) == 5)


def _chunk(t_obs_ns: int, phase: float = 0.0, h: int = 25, dt_ns: int = 20 * MS) -> ActionChunk:
    return ActionChunk(_wave((t_obs_ns + (np.arange(h) + 1) * dt_ns) * 1e-9, phase), t_obs_ns, dt_ns)


@pytest.mark.parametrize("actions, dt, why", [
    (np.full((5, 6), np.nan), 20 * MS, "non-finite"),
    (np.full((5, 6), np.inf), 20 * MS, "non-finite"),
    (np.zeros((0, 6)), 20 * MS, "shape"),
    (np.zeros((5, 7)), 20 * MS, "shape"),
    (np.zeros(6), 20 * MS, "2-D"),
    (np.full((5, 6), 1e9), 20 * MS, "beyond the limits"),
    (np.zeros((5, 6)), 0, "dt_ns"),
    (np.zeros((5, 6)), 0.02, "dt_ns"),
])
def test_malformed_chunks_become_events(actions, dt, why):
    ex = Executor(PROFILE, Q0, MS)
    events = ex.push(ActionChunk(actions, 0, dt), 0)
    assert [e.kind for e in events] == ["chunk_rejected"] and why in events[0].reason
    assert np.array_equal(ex.reference(MS), Q0)


def test_late_steps_are_dropped_not_replayed():
    """Observed while the reference moved (a chunk in use): the robot went on meanwhile, so the steps behind the
    playback clock are dropped."""
    ex = Executor(PROFILE, Q0, MS)
    ex.push(_chunk(0), 0)
    for t in range(0, 350):
        ex.reference(t * MS)
    late = _chunk(100 * MS)
    events = ex.push(late, 350 * MS)  # arrives 250 ms after its observation
    assert events[0].kind == "chunk_steps_dropped" and events[0].reason.startswith("12 ")
    stale = ex.push(_chunk(-600 * MS + 1), 350 * MS)  # older than the one in use
    assert stale[0].kind == "chunk_rejected" and "out of order" in stale[0].reason
    # once the blend from the old reference has decayed, the reference is the late chunk's curve at now,
    # not its first steps replayed from now on
    q = [ex.reference(t * MS) for t in range(351, 600)][-1]
    assert np.abs(q - _wave(np.array([0.599]))[0]).max() < 1e-3


def test_a_fully_stale_chunk_is_refused():
    ex = Executor(PROFILE, Q0, MS)
    assert ex.push(_chunk(0, h=5), 500 * MS)[0].kind == "chunk_stale"


def test_stitching_keeps_position_velocity_and_acceleration_continuous():
    ex = Executor(PROFILE, Q0, MS)
    ref = []
    for k in range(1500):
        t = k * MS
        if k % 50 == 10:
            ex.push(_chunk(t - 10 * MS, phase=0.02 * (k // 50)), t)  # each chunk disagrees a little more
        ref.append(ex.reference(t))
    ref = np.array(ref[300:])  # after the first blend, from standstill onto the moving chunk
    v = np.diff(ref, axis=0) / 1e-3
    a = np.diff(v, axis=0) / 1e-3
    j = np.diff(a, axis=0) / 1e-3
    # a step of velocity or acceleration would show as a spike: bounded jerk means neither steps
    assert np.abs(j).max() < 200.0
    assert np.abs(np.diff(v, axis=0)).max() < 0.02


def test_a_chunk_inside_the_limits_is_read_exactly_at_its_steps():
    ex = Executor(PROFILE, Q0, MS, blend_ns=20 * MS)
    chunk = _chunk(0)
    ex.push(chunk, 0)
    ex.reference(0)
    for i in range(5, 20):
        t = (i + 1) * 20 * MS
        for tick in range(t - 20 * MS + MS, t + MS, MS):
            r = ex.reference(tick)
        assert np.allclose(r, chunk.actions[i], atol=1e-12)


def test_speed_scale_stretches_time_along_the_same_path():
    ex = Executor(PROFILE, Q0, MS)
    ex.push(_chunk(0, h=50), 0)
    full = [ex.reference(k * MS) for k in range(400)]
    ex2 = Executor(PROFILE, Q0, MS)
    ex2.push(_chunk(0, h=50), 0)
    half = [ex2.reference(k * MS, 0.5) for k in range(799)]
    assert np.allclose(half[-1], full[399 // 1], atol=1e-3)
    assert ex2.tau_ns == pytest.approx(399 * MS, abs=MS)


def _played(chunks, every_ms: int, latency_ms: int, ticks: int) -> np.ndarray:
    """The elbow's reference, one chunk from ``chunks(k)`` every ``every_ms`` answering the observation
    ``latency_ms`` before it is pushed."""
    ex = Executor(PROFILE, Q0, MS)
    out, pending = [], None
    for k in range(ticks):
        t = k * MS
        if k % every_ms == 0:
            pending = (ActionChunk(chunks(k), t, 20 * MS), t + latency_ms * MS)
        if pending is not None and t >= pending[1]:
            ex.push(pending[0], t)
            pending = None
        out.append(ex.reference(t)[2])
    return np.array(out[500:])


def test_noise_between_a_policys_steps_is_not_amplified_by_the_stitching():
    """1 mrad of noise between steps became 22 mrad rms of reference error (65 mrad at most): the offset blend
    carried each chunk's spline velocity and acceleration at the switch, and compounded them."""
    rng = np.random.default_rng(0)

    def noisy(k):
        actions = np.repeat(Q0[None], 10, axis=0)
        actions[:, 2] += rng.normal(0.0, 1e-3, 10)
        return actions

    error = _played(noisy, 50, 10, 6000) - Q0[2]
    assert np.sqrt(np.mean(error ** 2)) < 1e-3 and np.abs(error).max() < 4e-3


@pytest.mark.parametrize("horizon", [10, 25])
def test_a_zig_zag_chunk_is_played_within_its_span(horizon):
    """Every chunk alternates the elbow by 3 mrad: the reference overshot by 45 mrad, 15 times the amplitude."""
    actions = np.repeat(Q0[None], horizon, axis=0)
    actions[1::2, 2] -= 0.003
    q = _played(lambda k: actions, 50, 0, 4000)
    assert Q0[2] - 0.003 - 1e-4 <= q.min() and q.max() <= Q0[2] + 1e-4


@settings(max_examples=60, deadline=None)
@given(st.integers(5, 400), st.integers(10, 1000), st.lists(st.floats(-0.2, 0.2), min_size=2, max_size=8))
def test_held_chunks_are_blended_within_their_span_whatever_the_timing(every_ms, blend_ms, levels):
    """Chunks 0.9 to 1 blend apart gave a finished curve a negative weight: 61 mrad outside the span."""
    ex = Executor(PROFILE, Q0, MS, blend_ns=blend_ms * MS)
    lo, hi = min(0.0, *levels), max(0.0, *levels)
    for k in range(3000):
        t = k * MS
        if k and k % every_ms == 0:
            ex.push(ActionChunk(np.repeat((Q0 + levels[(k // every_ms) % len(levels)])[None], 25, axis=0), t,
                                20 * MS), t)
        q = ex.reference(t) - Q0
        assert lo - 1e-9 <= q.min() and q.max() <= hi + 1e-9, (k, q)


def test_a_curve_fades_out_before_it_ends_so_a_long_blend_does_not_lag_the_plan():
    """A 1 s blend over 100 ms chunks weighed curves held past their end: the reference lagged a moving plan and
    the tracker was driven into its limits (limit_brake in a scripted run)."""
    ex = Executor(PROFILE, Q0, MS, blend_ns=1000 * MS)
    plan = lambda t_ns: Q0 + 0.5 * t_ns * 1e-9 * (np.arange(6) == 2)  # noqa: E731 - the elbow ramps at 0.5 rad/s
    worst = 0.0
    for k in range(3000):
        t = k * MS
        if k % 20 == 0:
            steps = t + (np.arange(5) + 1) * 20 * MS
            ex.push(ActionChunk(np.array([plan(s) for s in steps]), t, 20 * MS), t)
        q = ex.reference(t)
        if k > 1500:
            worst = max(worst, float(np.abs(q - plan(t)).max()))
    assert worst < 1e-6
