"""Executor: a chunk taken while the reference rests (the run's first, or after a curve ended) is entered without
the hold's lag: a crossfade from a hold caught up with a plan from rest at twice its acceleration."""

from __future__ import annotations

import numpy as np
import pytest

from cellguard.control.executor import Executor
from cellguard.control.guard import Guard
from cellguard.policy.chunk import ActionChunk
from cellguard.robot.registry import make_cell

PROFILE = make_cell("arm-pick-place").profile
Q0 = np.array([0.0, -0.3, 1.9, 1.55, 0.0, 0.025])
MS = 1_000_000
ELBOW = 2


def _from_rest(t_s: np.ndarray, peak: float = 10.0, jerk: float = 100.0) -> np.ndarray:
    """The elbow from rest at t = 0 under a jerk limit: acceleration ramps to ``peak`` [rad/s²], then holds."""
    ramp = peak / jerk
    x = np.where(t_s < ramp, jerk * t_s**3 / 6,
                 jerk * ramp**3 / 6 + peak * ramp / 2 * (t_s - ramp) + peak * (t_s - ramp) ** 2 / 2)
    return Q0 + x[:, None] * (np.arange(6) == ELBOW)


def _chunk(actions_of, t_obs_ns: int = 0, horizon: int = 10) -> ActionChunk:
    return ActionChunk(actions_of((t_obs_ns + (np.arange(horizon) + 1) * 20 * MS) * 1e-9), t_obs_ns, 20 * MS)


@pytest.mark.parametrize("rest_ms", [0, 300])  # the first chunk; one after the last chunk's curve has ended
def test_a_plan_from_rest_inside_the_limits_is_entered_inside_them(rest_ms):
    """A learned arm policy's first chunk, 7.2 rad/s² at most, was entered at 15.02 against a 15 limit: a limit
    intervention at the start of every run."""
    ex = Executor(PROFILE, Q0, MS)
    t0 = 0
    if rest_ms:
        ex.push(_chunk(lambda t: np.repeat(Q0[None], len(t), axis=0)), 0)
        t0 = rest_ms * MS
    ref = []
    for k in range(t0 // MS, t0 // MS + 190):
        if k * MS == t0 + 10 * MS:  # answered the observation at t0, taken 10 ms later
            ex.push(_chunk(lambda t: _from_rest(t - t0 * 1e-9), t0), k * MS)
        ref.append(ex.reference(k * MS)[ELBOW])
    acceleration = np.diff(ref, 2) / 1e-6
    # 10 rad/s² at most in the plan; the crossfade from the hold: 18.1, this one 11.5
    assert np.abs(acceleration).max() < PROFILE.array("acceleration")[ELBOW]


def test_a_guard_passes_a_first_chunk_from_rest_untouched():
    guard = Guard(PROFILE, Q0, MS)
    events = []
    for k in range(190):
        if k == 10:
            events += guard.push(_chunk(_from_rest), k * MS)
        setpoint, new = guard.tick(k * MS)
        events += new
        assert np.array_equal(setpoint, guard.reference)
    assert events == []


@pytest.mark.parametrize("horizon", [10, 25])
def test_a_noisy_first_chunk_is_entered_within_its_span(horizon):
    """The curve's velocity and acceleration at the switch, extrapolated, carried a 3 mrad zig-zag 0.17 rad away:
    such a joint fades out of the hold."""
    zig_zag = np.repeat(Q0[None], horizon, axis=0)
    zig_zag[1::2, ELBOW] -= 0.003
    ex = Executor(PROFILE, Q0, MS)
    ex.push(ActionChunk(zig_zag, 0, 20 * MS), 10 * MS)
    q = np.array([ex.reference(k * MS)[ELBOW] for k in range(10, 200)])
    assert Q0[ELBOW] - 0.003 - 1e-3 <= q.min() and q.max() <= Q0[ELBOW] + 1e-3


def test_a_one_step_chunk_from_rest_is_reached_smoothly():
    ex = Executor(PROFILE, Q0, MS)
    ex.reference(0)
    assert ex.push(ActionChunk((Q0 + 0.005)[None], 0, 20 * MS), 5 * MS) == []
    q = np.array([ex.reference(k * MS) for k in range(5, 400)])
    assert np.allclose(q[-1], Q0 + 0.005) and np.abs(np.diff(q, 2, axis=0)).max() / 1e-6 < 1.0


def test_a_first_plan_taken_late_starts_at_its_first_step():
    """The robot waited at rest while the policy thought: a pi0-shaped plan (1 s) taken 450 ms after its
    observation had its first 22 steps cut, and the blend from rest made up 0.63 rad of their motion in 200 ms
    (the tracker lagged the plan by as much). Now it plays from its first step, as if observed when taken."""
    ex = Executor(PROFILE, Q0, MS)
    ex.reference(0)
    plan = _chunk(_from_rest, 0, horizon=50)
    assert ex.push(plan, 450 * MS) == []  # nothing dropped
    ref = np.array([ex.reference((450 + k) * MS)[ELBOW] for k in range(0, 1000)])
    expected = _from_rest(np.arange(1000) * 1e-3)[:, ELBOW]  # the plan, 450 ms later
    assert np.abs(ref - expected).max() < 1e-3
    assert np.abs(np.diff(ref, 2)).max() / 1e-6 < PROFILE.array("acceleration")[ELBOW]


def test_after_a_chunk_ran_out_a_late_chunk_drops_its_past_steps():
    """The reference rests once a chunk has ended, but the setpoint may still be braking: a late chunk observed
    there is not re-timed (replayed, its steps repeated motion the robot had made)."""
    ex = Executor(PROFILE, Q0, MS)
    ex.push(_chunk(lambda t: np.repeat(Q0[None], len(t), axis=0)), 0)
    for k in range(0, 300):
        ex.reference(k * MS)
    events = ex.push(_chunk(lambda t: _from_rest(t - 0.3), 300 * MS, horizon=50), 400 * MS)
    assert "chunk_steps_dropped" in [e.kind for e in events]
