"""The effort check's hold at slow servo rates: never shorter than asked, never one sample, and said as served.

Rounding the 50 ms hold to the nearest sample made it one sample at 20 Hz and below: the first sample over
stopped the robot (a grasp's peak), while the event still said "for 50 ms".
"""

from __future__ import annotations

import numpy as np
import pytest

from cellguard.control.checks.check import Tick
from cellguard.control.checks.effort import EffortLimit
from cellguard.robot.registry import make_cell
from cellguard.robot.state import State

PROFILE = make_cell("arm-pick-place").profile
HOLD_S = 0.05


def _samples_to_stop(dt_ns: int, hold_s: float = HOLD_S):
    """Feed one joint at its effort limit every sample; the number of the sample that stops, and the stop."""
    check, tick = EffortLimit(PROFILE, 0.98, hold_s, dt_ns), Tick()
    zero = np.zeros(PROFILE.dof)
    effort = zero.copy()
    effort[0] = PROFILE.array("effort")[0]
    for n in range(1, 1000):
        tick.t_ns, tick.state = n * dt_ns, State(n * dt_ns, zero, zero, effort, zero)
        stop = check.request(tick)
        if stop is not None:
            return n, stop
    raise AssertionError("no effort stop")


@pytest.mark.parametrize("hz, samples", [(1000, 50), (200, 10), (50, 3), (30, 2), (20, 2), (10, 2), (2, 2)])
def test_the_hold_is_whole_samples_never_shorter_than_asked_and_never_one(hz, samples):
    dt_ns = round(1e9 / hz)
    n, stop = _samples_to_stop(dt_ns)
    assert n == samples
    assert n * dt_ns >= HOLD_S * 1e9


@pytest.mark.parametrize("hz, words", [(1000, "for 50 ms (50 samples of 1 ms)"), (50, "for 60 ms (3 samples of 20 ms)"),
                                       (20, "for 100 ms (2 samples of 50 ms)"),
                                       (2, "for 1000 ms (2 samples of 500 ms)")])
def test_the_event_says_the_hold_served(hz, words):
    _, stop = _samples_to_stop(round(1e9 / hz))
    assert stop.detail.reason == f"effort above 98% of the limit {words}"


def test_a_single_peak_never_stops_even_with_a_hold_shorter_than_a_sample():
    n, _ = _samples_to_stop(1_000_000, hold_s=0.0005)
    assert n == 2
