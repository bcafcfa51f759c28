"""IK answers stay inside the guard's soft limits, so a target past one fails the call instead of being chased.

Bounded by the MJCF's joint ranges (the arm's pan 2.6 rad, the profile's 2.5, the guard's soft limit 2.4), a sweep
of the pan angle to 2.58 rad at the home radius and height was "reached" at every step; the guard held the pan at
2.4 rad, the tool missed by up to 24 mm, and the record showed only limit interventions.
"""

import copy

import numpy as np
import pytest

from cellguard.control.envelope import Envelope
from cellguard.embodiment.action_map import parse_action_map
from cellguard.policy.adapter import InferenceError
from cellguard.policy.ik import IkSolver
from cellguard.robot.arm_cell import ArmPickPlace

XYZ_MAP = {"robot": "arm-pick-place",
           "actions": [{"name": "x", "ee": "x", "unit": "m"}, {"name": "y", "ee": "y", "unit": "m"},
                       {"name": "z", "ee": "z", "unit": "m"}],
           "hold": {"wrist_roll": "0 rad", "gripper": "0.025 m"},
           "ik": {"site": "tcp", "joints": ["shoulder_pan", "shoulder_lift", "elbow", "wrist_flex"],
                  "mode": "absolute"}}


@pytest.fixture(scope="module")
def arm():
    cell = ArmPickPlace()
    amap = parse_action_map(XYZ_MAP, cell.profile)
    solver = IkSolver(copy.deepcopy(cell.model), cell.profile, amap.ik)
    tracker = Envelope(cell.profile, cell.q_home, cell.dt_ns).tracker  # the guard's soft limits, default settings
    return cell, amap, solver, tracker.lo, tracker.hi


def _pan_sweep(solver, q_home, angles):
    """Tool targets at the home pose's radius and height, the base turned to each of ``angles`` [rad]."""
    home = solver.pose(q_home)[:3]
    radius = np.hypot(home[0], home[1])
    return np.column_stack([radius * np.cos(angles), radius * np.sin(angles), np.full(len(angles), home[2])])


def test_a_sweep_inside_the_soft_limit_is_reached_with_every_joint_inside_the_guards_limits(arm):
    cell, amap, solver, lo, hi = arm
    pan = cell.profile.index("shoulder_pan")
    targets = _pan_sweep(solver, cell.q_home, np.linspace(0.0, hi[pan] - 0.005, 100))
    q = amap.to_robot(targets, cell.q_home, solver)
    assert ((q >= lo) & (q <= hi)).all()  # the guard passes every step as asked
    reached = np.array([solver.pose(row)[:3] for row in q])
    assert np.linalg.norm(reached - targets, axis=1).max() < 1e-3  # [m]


def test_a_sweep_past_the_soft_limit_fails_at_the_first_step_beyond_it_naming_the_joint(arm):
    cell, amap, solver, lo, hi = arm
    pan = cell.profile.index("shoulder_pan")
    angles = np.linspace(0.0, 2.58, 100)  # the profile's hard limit is 2.5 rad
    first_missed = int(np.argmax(angles > hi[pan] + 1e-3 / 0.13))  # 1 mm of arc at the ~134 mm radius
    with pytest.raises(InferenceError, match=rf"IK: step {first_missed}: .* held at the guard's soft limit: "
                                             rf"shoulder_pan at {hi[pan]:.3f} rad; chunk refused"):
        amap.to_robot(_pan_sweep(solver, cell.q_home, angles), cell.q_home, solver)


def test_a_target_between_the_soft_and_the_hard_limit_is_refused(arm):
    """Inside the profile's hard limit, so bounding the IK by the profile alone still chased it: the guard brakes
    the joint before its soft limit."""
    cell, amap, solver, lo, hi = arm
    pan = cell.profile.index("shoulder_pan")
    between = 0.5 * (hi[pan] + cell.profile.q_max[pan])
    start = cell.q_home.copy()
    start[pan] = hi[pan] - 0.1
    with pytest.raises(InferenceError, match="held at the guard's soft limit: shoulder_pan"):
        amap.to_robot(_pan_sweep(solver, cell.q_home, np.array([between])), start, solver)
