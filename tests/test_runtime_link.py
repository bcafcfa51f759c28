"""The robot link: a state that is not finite or stamped ahead of the loop is a named fault, never used."""

from __future__ import annotations

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


def test_a_state_stamped_ahead_of_the_loop_is_stale_too():
    events = []
    link = RobotLink(_Bus(lambda s: s._replace(t_ns=s.t_ns + 500_000_000), bad_from=0), events,
                     stop_category=2, stale_ns=20_000_000)
    link.read(0)
    assert [e.kind for e in events] == ["robot_state_stale"] and "ahead of the loop's clock" in events[0].reason
    assert link.stop == 2


def test_no_transition_is_planned_from_a_pose_that_is_not_finite():
    profile = make_cell("arm-pick-place").profile
    start = np.zeros(profile.dof)
    start[0] = np.nan
    assert Transition.plan(profile, start, np.full(profile.dof, 0.1), 1_000_000) is None
