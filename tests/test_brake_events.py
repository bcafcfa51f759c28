"""A joint held braked at its soft limit is one ``limit_brake`` event, not one per tick the tracker switches to braking.

A reference beyond the gripper's lower limit held the gripper's setpoint at its soft limit while the arm's other
joints moved: the tracker switched the gripper between braking and recovery every few ticks, and each switch was an
event (1126 in a 12 s cycle of an ONNX policy asking for the gripper at 0). A brake of another joint, or before the
other limit, within the quiet period is still an event of its own.
"""

from __future__ import annotations

import numpy as np

from cellguard.control.config import GuardConfig
from cellguard.control.envelope import INTERVENTION_QUIET_NS, Envelope
from cellguard.control.tracker import STOP
from cellguard.robot.registry import make_cell

CELL = make_cell("arm-pick-place")
PROFILE = CELL.profile
LO, HI = PROFILE.q_min, PROFILE.q_max
MARGIN = GuardConfig().soft_margin * (HI - LO)
GRIPPER, ROLL = PROFILE.joint_names.index("gripper"), PROFILE.joint_names.index("wrist_roll")
DT_NS = 1_000_000


def _held_at_the_lower_limit() -> tuple[Envelope, list, int, int]:
    """The gripper's setpoint two ulps past its lower soft limit (where the approach to a clipped target left it),
    its reference at 0 beyond the hard limit, the arm moving to another pose for 3 s: the envelope, its brake
    events, how many times the tracker switched the gripper to braking, and the last tick it braked it [ns]."""
    q0 = CELL.read().q.copy()
    q0[GRIPPER] = 0.006460000000000002
    assert 0.0 < q0[GRIPPER] - (LO + MARGIN)[GRIPPER] < 1e-17
    envelope = Envelope(PROFILE, q0, DT_NS)
    reference = q0.copy()
    reference[[1, 2, 3, GRIPPER]] = 0.0, 1.0, 1.0, 0.0
    brakes, switches, last, mode = [], 0, None, envelope.tracker.mode[GRIPPER]
    for k in range(1, 3001):
        _, events = envelope.apply(k * DT_NS, reference)
        brakes += [e for e in events if e.kind == "limit_brake"]
        now = envelope.tracker.mode[GRIPPER]
        switches += now == STOP and mode != STOP
        last = k * DT_NS if now == STOP else last
        mode = now
    return envelope, brakes, switches, last


def test_a_joint_held_braked_at_its_soft_limit_is_one_event():
    _, brakes, switches, _ = _held_at_the_lower_limit()
    assert switches >= 20  # the tracker did switch back and forth (53 times when this was written)
    assert [(e.joint, e.t_ns) for e in brakes] == [("gripper", brakes[0].t_ns)]
    assert brakes[0].sent < brakes[0].asked or brakes[0].asked == 0.0


def test_a_brake_of_another_joint_or_before_the_other_limit_is_an_event_within_the_quiet_period():
    """Right after the held brake, the gripper put just inside its upper soft limit and the wrist roll just inside
    its lower one (an operator reset), each with a reference beyond: both brakes are events, though the gripper braked a tick ago."""
    envelope, _, _, last = _held_at_the_lower_limit()
    t0 = 3000 * DT_NS
    q = envelope.tracker.p.copy()
    q[GRIPPER] = (HI - MARGIN)[GRIPPER] - 1e-9
    q[ROLL] = (LO + MARGIN)[ROLL] + 1e-9
    envelope.reset(q)
    reference = q.copy()
    reference[GRIPPER], reference[ROLL] = HI[GRIPPER] + 0.01, LO[ROLL] - 0.1
    brakes = []
    for k in range(1, 101):
        _, events = envelope.apply(t0 + k * DT_NS, reference)
        brakes += [e for e in events if e.kind == "limit_brake"]
    assert sorted(e.joint for e in brakes) == ["gripper", "wrist_roll"]
    assert all(e.t_ns - last < INTERVENTION_QUIET_NS for e in brakes)
    assert next(e for e in brakes if e.joint == "gripper").asked > HI[GRIPPER]
