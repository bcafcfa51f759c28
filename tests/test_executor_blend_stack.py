"""The blend's stacked segment coefficients are reused between ticks only while every curve stays in its segment:
the reference equals the weighted sum of the curves read one by one, also where chunks come faster than the blend
and the oldest curve drops out as a new one comes in (the number of curves, and of segments, unchanged)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from cellguard.control.executor import MAX_BLENDED, Executor, _fade
from cellguard.policy.chunk import ActionChunk
from cellguard.robot.registry import make_cell

PROFILE = make_cell("arm-pick-place").profile
Q0 = np.array([0.0, -0.3, 1.9, 1.55, 0.0, 0.025])
MS = 1_000_000


def _one_by_one(ex: Executor, tau: int) -> np.ndarray:
    """The blended reference read curve by curve (no stacking): from the oldest curve, each newer one takes over
    as its switch fades the blend before it out, ``c_n + w_n (c_n-1 + w_n-1 (... - c_n-1) - c_n)``."""
    curves = [c for c, _, _ in ex._older] + [ex._curve]  # oldest first
    reference = curves[0].at(tau)
    for (_, switched, blend), curve in zip(ex._older, curves[1:]):
        reference = curve.at(tau) + _fade((tau - switched) / blend) * (reference - curve.at(tau))
    return reference


def _run(every_ms: int, ticks: int, steps_ms: int, seed: int) -> float:
    """Largest gap between the executor's reference and the curves read one by one, chunks every ``every_ms``."""
    rng = np.random.default_rng(seed)
    ex, worst, t_obs = Executor(PROFILE, Q0, MS), 0.0, 0
    for k in range(ticks):
        t = k * MS
        if k % every_ms == 0:
            actions = Q0 + rng.normal(0.0, 0.02, (10, 6)) * (np.arange(6) < 5)
            ex.push(ActionChunk(actions, t_obs, steps_ms * MS), t)
            t_obs = t
        q = ex.reference(t)
        if ex._older:
            worst = max(worst, float(np.abs(q - _one_by_one(ex, ex.tau_ns)).max()))
            assert len(ex._stack[1]) == len(ex._older) + 1  # a curve whose blend is over leaves the stack too
    return worst


def test_chunks_faster_than_the_blend_read_the_curves_in_the_blend_now():
    """One chunk a tick with 1 ms steps: the blend holds MAX_BLENDED curves, the oldest replaced every tick."""
    assert _run(every_ms=1, ticks=MAX_BLENDED + 150, steps_ms=1, seed=0) < 1e-12


@settings(max_examples=25, deadline=None)
@given(every_ms=st.integers(1, 60), steps_ms=st.sampled_from([1, 3, 10, 20]), seed=st.integers(0, 2**16))
def test_the_reference_is_the_weighted_sum_of_its_curves(every_ms, steps_ms, seed):
    assert _run(every_ms, ticks=400, steps_ms=steps_ms, seed=seed) < 1e-12
