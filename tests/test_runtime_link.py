"""The robot link: a state that is not finite is a named fault, never used; one stamped ahead of the loop is a fault
whose data is used; one stamped out of date is handed over marked stale."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from cellguard.control.envelope import StaleState
from cellguard.robot.registry import make_cell
from cellguard.runtime.link import RobotLink
from cellguard.runtime.transitions import Transition


class _Bus:
    """The simulated arm behind a bus that, from read ``bad_from`` on, reports ``change(state)``."""

    def __init__(self, change, bad_from: int = 1):
        self.cell, self.change, self.bad_from, self.reads = make_cell("arm-pick-place"), change, bad_from, 0

    def read(self):
        state, self.reads = self.cell.read(), self.reads + 1
        return self.change(state) if self.reads > self.bad_from else state

    def write(self, q):
        return self.cell.write(q)


@pytest.mark.filterwarnings("error::RuntimeWarning")  # the event names it; numpy's overflow warning came on top
@pytest.mark.parametrize("field, value", [("q", np.nan), ("qd", np.inf), ("effort", np.nan), ("q", 1e200)])
def test_a_state_that_is_not_finite_is_a_read_fault_and_the_last_good_state_stands_in(field, value):
    def corrupt(state):
        bad = getattr(state, field).copy()
        bad[2] = value
        return state._replace(**{field: bad})

    events = []
    link = RobotLink(_Bus(corrupt), events, stop_category=1)
    good = link.read(0)
    for stand_in in (link.read(1_000_000), link.read(2_000_000)):  # its values, marked stale: no standstill read
        assert isinstance(stand_in, StaleState) and stand_in.t_ns == good.t_ns
        assert all(np.array_equal(getattr(stand_in, f), getattr(good, f)) for f in ("q", "qd", "effort"))
    assert [(e.kind, e.category) for e in events] == [("robot_read_failed", 1)] and link.stop == 1
    assert "not finite" in events[0].reason


def test_a_state_stamped_ahead_of_the_loop_is_a_fault_but_its_data_is_fresh():
    events = []
    link = RobotLink(_Bus(lambda s: s._replace(t_ns=s.t_ns + 500_000_000), bad_from=0), events,
                     stop_category=2, stale_ns=20_000_000)
    state = link.read(0)
    assert [e.kind for e in events] == ["robot_state_stale"] and "ahead of the loop's clock" in events[0].reason
    assert link.stop == 2
    assert not isinstance(state, StaleState)  # newer than the tick: a category 1 stop may read standstill from it


@dataclass
class _Reading:
    """A bridge's own state object: the State's fields by name, in another order, no tuple."""

    current: np.ndarray
    effort: np.ndarray
    qd: np.ndarray
    q: np.ndarray
    t_ns: int


def test_a_state_like_object_read_stale_or_standing_in_is_marked_by_its_fields_names():
    def reading(state):
        return _Reading(state.current, state.effort, state.qd + 1.0, state.q, state.t_ns)

    bus = _Bus(reading, bad_from=0)
    link = RobotLink(bus, [], stop_category=1, stale_ns=20_000_000)
    fresh = link.read(0)
    stale = link.read(50_000_000)  # the same stamp, 50 ms on
    assert isinstance(stale, StaleState) and stale.t_ns == fresh.t_ns
    assert np.array_equal(stale.qd, fresh.qd) and np.array_equal(stale.q, fresh.q)
    bus.read = lambda: {}["no state"]  # a bridge bug: the last good one stands in, marked by name too
    stand_in = link.read(51_000_000)
    assert isinstance(stand_in, StaleState) and np.array_equal(stand_in.effort, fresh.effort)


def test_no_transition_is_planned_from_a_pose_that_is_not_finite():
    profile = make_cell("arm-pick-place").profile
    start = np.zeros(profile.dof)
    start[0] = np.nan
    assert Transition.plan(profile, start, np.full(profile.dof, 0.1), 1_000_000) is None
