"""The tracker's loose stopping bound (what spares the exact check of a limit it clears) bounds the exact stop at
every state the fit tolerates, acceleration up to a_max (1 + 1e-9) + 1e-12 included: built from a_max alone, the
exact stop went 1e-11 past it, and on a joint whose soft range is shorter than twice the bound (a 5 mm gripper) a
sample the bound cleared on one side, unchecked there, stopped 3e-12 past the soft limit."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from cellguard.control.tracker import Tracker
from cellguard.robot.registry import make_cell

PROFILE = make_cell("arm-pick-place").profile
GRIPPER = 5  # the arm's gripper: the shortest range and the largest stopping bound relative to it
V, A, J = (PROFILE.array(k)[GRIPPER] for k in ("velocity", "acceleration", "jerk"))
DT = 1e-3


@settings(max_examples=400, deadline=None)
@given(hi=st.sampled_from([0.005, 0.01, 0.0221]), a=st.floats(-1.0, 1.0), v_end=st.floats(-1.0, 1.0),
       near=st.floats(0.0, 1.0), upper=st.booleans())
def test_a_sample_that_fits_stops_inside_both_soft_limits(hi, a, v_end, near, upper):
    tracker = Tracker(np.zeros(1), [V], [A], [J], [0.0], [hi], DT)
    a, v_end = a * (A * (1.0 + 1e-9) + 1e-12), v_end * V
    v = v_end - a * DT / 2  # the tick's mean velocity whose end is v_end
    far = tracker._far0[0] + abs(v_end) * (tracker._far1[0] + abs(v_end) * tracker._far2[0])
    q = max(hi - far * near, 0.0) if upper else min(far * near, hi)  # from the bound's edge inward, inside
    tracker.samples = ([q - v * DT], [v - a * DT], [a])
    (fit,), (v,), (a,) = tracker._fits([q])
    if fit:
        v_end = v + a * DT / 2  # as the fit reads the state: the velocity at the end of the tick
        assert q + tracker._stop_distance(0, v_end, a) <= hi
        assert q - tracker._stop_distance(0, -v_end, -a) >= 0.0


@settings(max_examples=2000, deadline=None)
@given(a=st.floats(-1.0, 1.0), v=st.floats(-1.5, 1.5))
def test_the_loose_bound_is_above_the_exact_stop_at_the_tolerated_acceleration(a, v):
    tracker = Tracker(np.zeros(1), [V], [A], [J], [-1.0], [1.0], DT)
    a, v = a * (A * (1.0 + 1e-9) + 1e-12), v * V
    far = tracker._far0[0] + abs(v) * (tracker._far1[0] + abs(v) * tracker._far2[0])
    assert tracker._stop_distance(0, v, a) <= far and tracker._stop_distance(0, -v, -a) <= far
