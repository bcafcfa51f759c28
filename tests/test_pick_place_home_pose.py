"""A pick-place cell's profile lists its joints in the model's order, and its home pose puts the tool point inside the
layout's workspace box; else the cell is refused when built. A plugin whose profile swapped shoulder_pan and elbow
built, its home put shoulder_pan at the elbow's 1.9 rad, and its run stopped at the first chunk as 'policy_lost ...
lies outside the workspace box'; a layout box that left out the home tool point stopped the same way."""

from __future__ import annotations

import dataclasses

import pytest
from test_pick_place_fit import ARM, ARM_JOINTS, _cell, _joints, run_arm_plugin

from cellguard.errors import ProfileError
from cellguard.robot.arm_cell import LAYOUT

SWAPPED = ("elbow", "shoulder_lift", "shoulder_pan", *ARM_JOINTS[3:])


def test_a_profile_in_another_order_than_the_models_is_refused(tmp_path):
    with pytest.raises(ProfileError, match=r": its joints \(elbow, shoulder_lift, shoulder_pan, wrist_flex, "
                                           r"wrist_roll, gripper\) are not in the model's order \(shoulder_pan, "
                                           r"shoulder_lift, elbow, wrist_flex, wrist_roll, gripper\); q_home and "
                                           r"every action follow"):
        _cell(tmp_path, _joints(ARM, SWAPPED))


def test_a_layout_whose_box_leaves_out_the_home_tool_point_is_refused(tmp_path):
    low = dataclasses.replace(LAYOUT, workspace_box=((-0.45, -0.45, 0.005), (0.45, 0.45, 0.15)))
    with pytest.raises(ProfileError, match=r": the home pose puts the tool point at \[0.134, 0.0, 0.194\] m, outside "
                                           r"the layout's workspace_box \[\[-0.45, -0.45, 0.005\], \[0.45, 0.45, "
                                           r"0.15\]\] m$"):
        _cell(tmp_path, ARM, layout=low)
    assert _cell(tmp_path, ARM, layout=dataclasses.replace(LAYOUT, workspace_box=(
        (-0.45, -0.45, 0.005), (0.45, 0.45, 0.2)))).layout.workspace_box[1][2] == 0.2  # the tip within: built


def test_a_plugin_cell_with_reordered_joints_is_one_line_naming_its_file_and_nothing_runs(tmp_path):
    folder, ran = run_arm_plugin(tmp_path, "swapped", _joints(ARM, SWAPPED))
    assert ran.returncode == 2, ran.stderr
    [line] = ran.stderr.strip().splitlines()
    assert line.startswith(f"error: cell 'swapped-pick-place': its plugin swapped ({folder / 'swapped.py'}): profile "
                           "'swapped-pick-place' version 2026-11-01: its joints (elbow, "), line
    assert not (tmp_path / "out").exists()
