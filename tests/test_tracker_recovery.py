"""The tracker's recovery lands back on the reference and hands back to pass-through, without a runaway.

A reference that starts with a step in acceleration (one tick over the jerk limit, inside every other limit)
is handed to ruckig; so is a joint a category 2 stop left off its moving reference. Before, the error plan
took the reference's velocity at mid-tick while the setpoint's was at the end of the tick, so each hand-over
from an absolute plan stepped the velocity by half a tick of the reference's acceleration; the next offset
plan broke the jerk limit, the absolute plan restarted from the samples, and the two alternated every tick,
pumping the acceleration up until the setpoint ran off at the acceleration limit. And a joint was handed back
on the first tick its sample fitted, crossing the reference at speed: the next sample broke the jerk limit
and the recovery started over, for as long as the reference moved.
"""

from __future__ import annotations

import numpy as np
import pytest

from cellguard.control.envelope import Envelope
from cellguard.control.tracker import PASS, Tracker
from cellguard.robot.protocol import SafetyInputs
from cellguard.robot.registry import make_cell

PROFILE = make_cell("arm-pick-place").profile
DT = 1e-3
LO, HI = PROFILE.q_min, PROFILE.q_max
MID = 0.5 * (LO + HI)
V, A, J = PROFILE.array("velocity"), PROFILE.array("acceleration"), PROFILE.array("jerk")
V_TOL, A_TOL, J_TOL = 2e-3, 2e-2, 0.2  # as in test_guard_limits


def _derivatives(q):
    v = np.diff(q, axis=0) / DT
    a = np.diff(v, axis=0) / DT
    return v, a, np.diff(a, axis=0) / DT


def _assert_within_limits(q, limits=(V, A, J)):
    for x, limit, tol in zip(_derivatives(q), limits, (V_TOL, A_TOL, J_TOL)):
        assert (np.abs(x) <= limit * (1 + tol)).all(), np.abs(x).max(axis=0) / limit


@pytest.mark.parametrize("a0", [3.0, 5.0])
def test_a_start_with_a_step_in_acceleration_lands_back_on_the_reference(a0):
    """At rest, then a constant acceleration (a third of the limit at most; its first tick is 1.5 to 2.5 times
    the jerk limit): at 3 rad/s² it ran off, 0.13 rad ahead of the reference half a second later, at the
    velocity limit."""
    tracker = Tracker([0.5], [3.0], [15.0], [1000.0], [-3.0], [3.0], DT)
    ticks = 700
    t = np.maximum(np.arange(1, ticks + 1) * DT - 0.2, 0.0)
    reference = 0.5 + 0.5 * a0 * t * t  # 1.5 rad/s at most: inside the velocity limit throughout
    out = np.array([tracker.follow(np.array([x]))[0] for x in reference])
    assert (out[:200] == reference[:200]).all()  # at rest: passed through
    assert (out[200:] != reference[200:]).any()  # the step was not passed through
    assert (out[-200:] == reference[-200:]).all() and tracker.passing  # landed, handed back
    _assert_within_limits(np.concatenate([[0.5], out])[:, None], (3.0, 15.0, 1000.0))


def test_after_a_category_2_stop_the_setpoint_lands_back_on_its_reference():
    """A stop mid-motion leaves the arm behind its reference (here up to 0.14 rad), which moves on and speeds up
    after the release. Before, the setpoint ran off it at the acceleration limit on several joints and the
    recovery never ended."""
    amp = 0.15 * (HI - LO)
    w = np.min([0.5 * V / amp, np.sqrt(0.3 * A / amp), np.cbrt(0.3 * J / amp)], axis=0)
    ticks, stop, release = 1500, 100, 250
    envelope = Envelope(PROFILE, MID, 1_000_000)
    out, refs, resumed = [MID], [MID], []
    for k in range(1, ticks + 1):
        r = MID + amp * (1.0 - np.cos(w * k * DT))
        setpoint, events = envelope.apply(k * 1_000_000, r, None, SafetyInputs(stop=2 if stop <= k < release else None))
        out.append(setpoint)
        refs.append(r)
        resumed += [k for e in events if e.kind.value == "resume"]
    out, refs = np.array(out), np.array(refs)
    assert len(resumed) == 1 and np.abs(out[resumed[0]] - refs[resumed[0]]).max() > 0.05
    assert (out[-300:] == refs[-300:]).all() and envelope.tracker.passing  # landed, handed back
    _assert_within_limits(out[resumed[0]:])
