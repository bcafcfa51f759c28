"""A transition aborted on its first tick, from a command still moving (a time cycle that ended mid-motion), is
braked under the limits from that motion: the brake returned None there (``steps <= 0``), and the command stopped
dead at full speed."""

from __future__ import annotations

import numpy as np

from cellguard.robot.registry import make_cell
from cellguard.runtime.transitions import Transition

MS = 1_000_000


def test_a_transition_aborted_before_its_first_setpoint_brakes_from_the_commands_motion():
    profile = make_cell("arm-pick-place").profile
    start = np.array([0.0, -0.3, 1.9, 1.55, 0.0, 0.025])
    velocity = 0.8 * profile.array("velocity") * np.array([1, -1, 1, 0, 0, 0])
    plan = Transition.plan(profile, start, start + 0.5, MS, velocity=velocity)
    brake = plan.brake(profile, 0)
    assert brake is not None
    steps = np.diff(np.vstack([start, list(brake.setpoints())]), axis=0) / 1e-3  # [unit/s] per tick
    moving = velocity != 0
    assert np.allclose(steps[0][moving], velocity[moving], rtol=0.01)  # it carries on from the motion, no dead stop
    assert (np.abs(np.diff(steps, axis=0)) / 1e-3 <= profile.array("acceleration") * 1.01).all()  # under the limit
    assert np.abs(steps[-1]).max() < 1e-3  # and comes to rest


def test_a_transition_from_rest_aborted_at_once_has_nothing_to_brake():
    profile = make_cell("arm-pick-place").profile
    start = np.array([0.0, -0.3, 1.9, 1.55, 0.0, 0.025])
    assert Transition.plan(profile, start, start + 0.5, MS).brake(profile, 0) is None
