"""The arm-pick-place cell: the project's own 5-axis arm with a parallel gripper (``assets/arm.xml``).

The task (fixture, part, camera, drop zone, grasp) is ``cellguard.robot.pick_place``; this module
holds what is particular to this arm: its model, profile and layout.
"""

from __future__ import annotations

from pathlib import Path

import mujoco

from cellguard.embodiment import load_profile
from cellguard.robot.pick_place import CAMERA_ROTATION, Layout, PickPlaceCell

__all__ = ["ASSETS", "CAMERA_ROTATION", "LAYOUT", "PART_HALF", "ArmPickPlace"]

ASSETS = Path(__file__).parent / "assets"
PART_HALF = 0.015  # [m] half edge of the cube part
LAYOUT = Layout(
    part_half=PART_HALF,
    capture_radius=0.0025,
    capture_height=0.004,
    drop_tolerance=0.012,
    gripper_closed=0.0155,  # [m] finger opening below which the pads touch a centred part
    gripper_released=0.02,  # [m]
    q_home=(0.0, -0.3, 1.9, 1.55, 0.0, 0.025),
    # Tool-point box the guard keeps the tool in by default [m]: above the table, inside the reach.
    workspace_box=((-0.45, -0.45, 0.005), (0.45, 0.45, 0.55)),
    ik_joints=("shoulder_pan", "shoulder_lift", "elbow", "wrist_flex"),  # the wrist roll stays as at home
)


def load_model() -> mujoco.MjModel:
    """The cell's model as commissioned (no fault applied)."""
    return mujoco.MjModel.from_xml_path(str(ASSETS / "arm.xml"))


class ArmPickPlace(PickPlaceCell):
    """A simulated arm cell at a 1 ms servo period. Joint order is the profile's."""

    name = "arm-pick-place"

    def __init__(self, seed: int = 0):
        model = load_model()
        super().__init__(model, load_profile(model, ASSETS / "arm_profile.yaml"), LAYOUT, seed)

    @staticmethod
    def mjcf_spec() -> mujoco.MjSpec:
        """The commissioned MJCF as an editable spec (``identify --write`` writes a calibrated copy)."""
        return mujoco.MjSpec.from_file(str(ASSETS / "arm.xml"))
