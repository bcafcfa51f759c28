"""A tool point found outside the workspace box may be taken no further out wall by wall (``grown_box``): a wall it
is inside of stays a wall. Before, every wall was pushed out by how far out the tool was on its worst axis: a tool
33 mm over the ceiling swung 32 mm past a side wall it was inside of, in the guard (a later chunk), the approach
(``Transition.leaves_box``) and the start-up's first target alike, with no event."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from test_start_outside_box import NEAR, OUT, posed_run

from cellguard.control.checks.workspace import SLACK
from cellguard.control.config import GuardConfig
from cellguard.control.guard import Guard
from cellguard.control.reach import max_reach
from cellguard.policy.chunk import ActionChunk
from cellguard.robot.registry import make_cell
from cellguard.runtime import run_scenario
from cellguard.runtime.transitions import Transition

CELL = make_cell("arm-pick-place")
PROFILE, TOOL, MS = CELL.profile, CELL.tool_point, 1_000_000
BOX = ((-0.45, -0.02, 0.005), (0.45, 0.02, 0.25))  # a narrow box: the base's swing crosses its y max wall
SWING = OUT + [0.3, 0.0, 0.0, 0.0, 0.0, 0.0]  # the same height, 32 mm past y max


def test_a_guarded_swing_from_over_the_ceiling_stops_at_the_side_wall():
    guard = Guard(PROFILE, OUT, MS, GuardConfig(watchdog_s=10.0, box=BOX), tool=TOOL)
    guard.push(ActionChunk(np.linspace(OUT, SWING, 25), MS, 20 * MS), MS)
    tips, kinds = [], []
    for k in range(1500):
        setpoint, events = guard.tick((k + 1) * MS)
        tips.append(TOOL(setpoint))
        kinds += [e.kind for e in events]
    assert max(tip[1] for tip in tips) <= BOX[1][1]  # 54.6 mm before (32 mm past it)
    assert kinds == ["workspace_stop"]


def test_stops_between_chunks_do_not_let_a_tool_outside_the_box_creep_further_out():
    """A policy that asks each chunk a little higher, its chunks further apart than the watchdog: every watchdog stop
    regrew the box from where the tool then was, and the tool crept 33 -> 70 mm over the ceiling in 20 s."""
    guard = Guard(PROFILE, OUT, MS, GuardConfig(watchdog_s=0.1, box=BOX), tool=TOOL)
    start, highest = TOOL(OUT)[2], 0.0
    for k in range(8000):
        t = (k + 1) * MS
        if k % 400 == 0:
            target = OUT + [0.0, 0.0, -0.003 * (k // 400 + 1), 0.0, 0.0, 0.0]
            guard.push(ActionChunk(np.broadcast_to(target, (25, 6)).copy(), t - MS, 20 * MS), t)
        setpoint, _ = guard.tick(t)
        highest = max(highest, TOOL(setpoint)[2])
    assert highest <= start + SLACK + 1e-6, (highest - start) * 1e3


def test_an_approach_from_over_the_ceiling_past_a_side_wall_leaves_the_box():
    plan = Transition.plan(PROFILE, OUT, SWING, MS)
    why = plan.leaves_box(PROFILE, TOOL, BOX, max_reach(TOOL, PROFILE.q_min, PROFILE.q_max).norm)
    assert why is not None and "past its y max" in why, why
    down = Transition.plan(PROFILE, OUT, OUT + [0.0, 0.0, 0.3, 0.0, 0.0, 0.0], MS)  # back in under the ceiling
    assert down.leaves_box(PROFILE, TOOL, BOX, max_reach(TOOL, PROFILE.q_min, PROFILE.q_max).norm) is None


def test_an_approach_from_outside_the_box_says_how_far_past_where_it_may_go_not_that_it_leaves_the_box():
    """A tool that was never inside the box does not "leave" it: the approach from 33 mm over the ceiling to a target
    34.8 mm over it (35.2 mm allowed) goes 1 mm past that on the way."""
    plan = Transition.plan(PROFILE, OUT, NEAR, MS)
    wide = ((-0.45, -0.45, 0.005), (0.45, 0.45, 0.25))
    why = plan.leaves_box(PROFILE, TOOL, wide, max_reach(TOOL, PROFILE.q_min, PROFILE.q_max).norm)
    assert why == ("its tool point goes 1 mm past where it may go from its start outside the workspace box "
                   "(past no wall further than there, 2 mm spare), first past its z max 0.06 s in (at [0.181, 0.0, "
                   "0.285] m), the most past its z max 0.09 s in"), why  # the box itself named by the start


def test_a_first_target_past_a_side_wall_is_rejected_and_the_lost_line_names_the_start(tmp_path):
    np.savez(tmp_path / "p.npz", t=np.arange(60) * 0.1, actions=np.broadcast_to(SWING, (60, 25, 6)).copy(),
             dt=np.float64(0.02))
    run = posed_run(tmp_path / "p.npz", BOX)
    tips = []
    summary = run_scenario(run.scenario, tmp_path / "out", run=run,
                           on_cycle=lambda _: tips.append(run.guard.tool(run.link.state.q)))
    kinds = [e["kind"] for e in summary["events"]]
    assert "approach_begin" not in kinds and "chunk_rejected" in kinds, kinds
    assert summary["stopped"].startswith("policy lost: the tool point starts 33 mm outside the workspace box "), \
        summary["stopped"]
    assert "every first target or the way to it further out" in summary["stopped"]
    assert "32 mm past its y max, a wall the tool is inside of" in summary["stopped"]
    assert tips[0][1] <= BOX[1][1]  # held where it started (31.7 mm past y max all cycle before)


_coordinate = st.floats(-1.0, 1.0, allow_nan=False)
_points = st.tuples(_coordinate, _coordinate, _coordinate)


@given(_points, _points, _points, st.tuples(*[st.floats(0.01, 1.0)] * 3))
def test_the_grown_box_holds_a_target_exactly_where_no_wall_is_passed_further_than_the_start(start, target, then, size):
    from cellguard.control.checks.workspace import grown_box  # here: without it the module's other tests still run

    lo = (-0.5, -0.5, -0.5)
    hi = tuple(a + s for a, s in zip(lo, size))
    grown = grown_box(start, lo, hi)
    past = [(max(a - p, 0.0), max(p - b, 0.0)) for p, a, b in zip(start, lo, hi)]
    if grown is None:
        assert past == [(0.0, 0.0)] * 3
        return
    taken = all(a <= t <= b for t, a, b in zip(target, *grown))
    # per wall: one the start is inside of stays; one it is past may be passed as far as it is, SLACK more
    rule = all(lo[k] - t <= (below and below + SLACK) and t - hi[k] <= (above and above + SLACK)
               for k, (t, (below, above)) in enumerate(zip(target, past)))
    assert taken == rule
    shrunk = grown_box(then, lo, hi, grown)  # as the tool moves on, the allowance never grows
    assert all(s >= g for s, g in zip(shrunk[0], grown[0])) and all(s <= g for s, g in zip(shrunk[1], grown[1]))


def test_a_start_a_fraction_of_a_mm_out_is_named_to_a_tenth_of_a_mm_and_on_its_side_of_the_wall():
    from cellguard.runtime.startup import BoxStart  # here: without it the module's other tests still run

    start = BoxStart.of(((-0.45, -0.45, 0.005), (0.45, 0.45, 0.25)), np.array([0.1, 0.0, 0.2501]))
    assert "starts 0.1 mm outside" in str(start) and "(at [0.1, 0.0, 0.2501] m)" in str(start), str(start)
    assert start.further(np.array([0.1, 0.0, 0.25])) is None
    further = start.further(np.array([0.1, 0.0, 0.2532]))
    assert "further out, 3 mm past its z max (at [0.1, 0.0, 0.253] m)" in further, further
