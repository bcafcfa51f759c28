"""The LeRobot bridge's units map: every joint is read and commanded through an action key of the robot.

A LeRobot-like robot stands in (the bridge calls only its features, ``get_observation`` and ``send_action``),
so this runs without LeRobot.
"""

import numpy as np
import pytest

from cellguard.embodiment.action_map import identity_map, parse_action_map
from cellguard.errors import ConfigError
from cellguard.robot.arm_cell import ArmPickPlace
from cellguard.robot.bridges.lerobot import LeRobotBridge


class Robot:
    """Reports wrist_roll at 1.5 rad, the other joints at 0; keeps what it was sent."""

    name, id, is_connected = "fake_arm", "x", True

    def __init__(self, joints):
        self.action_features = {j: float for j in joints}
        self.observation_features = dict(self.action_features)
        self.position = {j: 1.5 if j == "wrist_roll" else 0.0 for j in joints}
        self.sent = []

    def get_observation(self):
        return dict(self.position)

    def send_action(self, action):
        self.sent.append(dict(action))
        return dict(action)


@pytest.fixture(scope="module")
def profile():
    return ArmPickPlace().profile


def test_a_units_map_that_holds_a_joint_is_refused_naming_it(profile):
    """A held wrist_roll read as its hold value (0) with the robot at 1.5 rad, and was never commanded: the guard's
    workspace and tool-speed checks worked from a pose the robot was not in."""
    held = parse_action_map({"robot": profile.robot, "hold": {"wrist_roll": "0 rad"},
                             "actions": [{"name": j, "joint": j, "unit": "m" if j == "gripper" else "rad"}
                                         for j in profile.joint_names if j != "wrist_roll"]}, profile)
    with pytest.raises(ConfigError, match=r"^units map: joints wrist_roll have no action key; the bridge reads and "
                                          r"commands every joint of a LeRobot robot through its key \(no hold\)$"):
        LeRobotBridge(Robot(profile.joint_names), profile, held, 20_000_000, lockstep=True)


def test_a_units_map_driving_every_joint_reads_where_the_robot_is(profile):
    robot = Robot(profile.joint_names)
    bridge = LeRobotBridge(robot, profile, identity_map(profile), 20_000_000, lockstep=True)
    assert bridge.read().q[profile.index("wrist_roll")] == pytest.approx(1.5)
    bridge.write(np.zeros(profile.dof))
    assert sorted(robot.sent[-1]) == sorted(profile.joint_names)


@pytest.mark.parametrize("arg", ["", "?port=/dev/ttyACM0"])
def test_a_bridge_without_a_robot_type_says_so_in_one_line(arg):
    from cellguard.robot.bridges.lerobot import make_lerobot_robot

    with pytest.raises(ConfigError, match=r"^robot: lerobot: missing target, write lerobot:TYPE\?port=\.\.\.&id=\.\.\.$"):
        make_lerobot_robot(arg)
