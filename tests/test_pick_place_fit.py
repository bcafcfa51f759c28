"""A pick-place cell's profile must fit its model and layout: one value of the home pose per profiled joint, the
gripper last, the home pose inside the position limits. A plugin cell whose profile missed or added a joint ended in a
numpy traceback; one with reordered joints, or a home pose outside its limits, ran (every chunk refused, or each
retreat to home braked at the limit)."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import mujoco
import pytest
from test_cell_plugin import install

from cellguard.embodiment import load_profile
from cellguard.errors import ProfileError
from cellguard.robot.arm_cell import ASSETS, LAYOUT, load_model
from cellguard.robot.pick_place import PickPlaceCell
from cellguard.robot.world_changes import ADDED, MULTIPLIED

ARM = (ASSETS / "arm_profile.yaml").read_text()
MIMIC = ('  gripper_mimic: {position: ["6 mm", "29 mm"], velocity: "0.25 m/s", acceleration: "4 m/s^2", '
         'jerk: "200 m/s^3", effort: "20 N", torque_constant: "8 N/A"}\n')


def _joints(text: str, order) -> str:
    """The arm profile with its joint lines in ``order`` (names; ``gripper_mimic`` is the model's second finger)."""
    lines = {line.split(":")[0].strip(): line for line in text.splitlines(keepends=True) if line.startswith("  ")
             and not line.startswith("  -")}
    lines["gripper_mimic"] = MIMIC
    head, rest = text.split("joints:\n")
    return head + "joints:\n" + "".join(lines[n] for n in order) + rest[rest.index("measured:"):]


ARM_JOINTS = ("shoulder_pan", "shoulder_lift", "elbow", "wrist_flex", "wrist_roll", "gripper")
NARROW = ARM.replace('wrist_flex:    {position: ["-2.1 rad", "2.1 rad"]',
                     'wrist_flex:    {position: ["-1.5 rad", "1.5 rad"]')  # the arm's home pose has it at 1.55


def _cell(tmp_path: Path, profile: str, model: mujoco.MjModel | None = None, layout=LAYOUT) -> PickPlaceCell:
    model = model or load_model()
    (tmp_path / "p.yaml").write_text(profile)
    return PickPlaceCell(model, load_profile(model, tmp_path / "p.yaml"), layout)


@pytest.mark.parametrize("profile, error", [
    (_joints(ARM, ARM_JOINTS[:-1]), r"profile 'arm-pick-place' version 2026-11-01: 5 joints \(shoulder_pan, "
                                    r"shoulder_lift, elbow, wrist_flex, wrist_roll\) for a home pose of 6 \(q_home"),
    (_joints(ARM, [*ARM_JOINTS, "gripper_mimic"]), r": 7 joints \(.*, gripper, gripper_mimic\) for a home pose of 6"),
    (_joints(ARM, ARM_JOINTS[::-1]), r": its last joint 'shoulder_pan' moves the tool; the gripper must be the last"),
    (_joints(ARM, [*ARM_JOINTS[:4], "gripper_mimic", "gripper"]),
     r": its joint 'gripper_mimic' does not move the tool; only the last one, the gripper, may not"),
    (NARROW, r": the home pose puts wrist_flex at 1.55 rad, outside its position limits \[-1.5, 1.5\] rad$"),
])
def test_a_profile_that_does_not_fit_the_cell_is_refused_naming_why(tmp_path, profile, error):
    with pytest.raises(ProfileError, match=error):
        _cell(tmp_path, profile)


def test_a_layout_whose_ik_joints_the_profile_lacks_is_refused(tmp_path):
    """Found at the first recovery, mid-run (``reach``'s ``names.index``), before."""
    layout = dataclasses.replace(LAYOUT, ik_joints=("shoulder_pan", "wrist_twist"))
    with pytest.raises(ProfileError, match=r"ik_joints \['wrist_twist'\] are not among its arm joints"):
        _cell(tmp_path, ARM, layout=layout)


def test_a_model_without_a_tool_body_is_refused(tmp_path):
    """Without one the cell took the model's last body for the tool and ran."""
    model = mujoco.MjModel.from_xml_string((ASSETS / "arm.xml").read_text().replace('"tool"', '"flange"'))
    with pytest.raises(ProfileError, match=r": its model has no body 'tool'$"):
        _cell(tmp_path, ARM, model=model)


def test_a_pick_place_cell_has_every_setter_a_fault_may_call(arm):
    """Why it simulates every fault kind found (``supported_faults``), a new file's too: a fault acts on the world
    only through these setters (``world_changes``), and on the policy channel."""
    assert all(callable(getattr(arm, setter, None)) for setter in ADDED | MULTIPLIED)


PLUGIN = '''
from pathlib import Path

from cellguard.embodiment import load_profile
from cellguard.robot.arm_cell import LAYOUT, load_model
from cellguard.robot.pick_place import PickPlaceCell


class Plugged(PickPlaceCell):
    """The arm with a site's own profile, beside this file."""
    name = "{dist}-pick-place"

    def __init__(self, seed=0):
        model = load_model()
        super().__init__(model, load_profile(model, Path(__file__).with_name("profile.yaml")), LAYOUT, seed)
'''


def run_arm_plugin(tmp_path: Path, dist: str, profile: str) -> tuple[Path, subprocess.CompletedProcess]:
    """``cellguard run`` of one cycle of plugin cell ``{dist}-pick-place``: the arm with the arm profile text
    ``profile`` as its own. Returns the plugin's folder and the finished command."""
    name = f"{dist}-pick-place"
    folder = install(tmp_path / dist, f"[cellguard.cells]\n{name} = {dist}:Plugged\n", PLUGIN.format(dist=dist), dist)
    (folder / "profile.yaml").write_text(profile.replace("robot: arm-pick-place", f"robot: {name}"))
    scenario = tmp_path / "s.yaml"
    scenario.write_text(f"cell: {name}\nacceptance_cycles: 1\nproduction_cycles: 0\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(folder), os.environ.get("PYTHONPATH", "")])}
    return folder, subprocess.run([sys.executable, "-c", "from cellguard.cli import app; app()", "run", str(scenario),
                                   "--out", str(tmp_path / "out")], env=env, capture_output=True, text=True,
                                  timeout=300)


def test_a_plugin_cell_whose_home_is_outside_its_limits_is_one_line_naming_its_file_and_nothing_runs(tmp_path):
    """The arm with a site's commissioning limits: wrist_flex within +-1.5 rad, and the arm's home pose at 1.55."""
    folder, ran = run_arm_plugin(tmp_path, "myarm", NARROW)
    assert ran.returncode == 2, ran.stderr
    assert ran.stderr.strip().splitlines() == [
        f"error: cell 'myarm-pick-place': its plugin myarm ({folder / 'myarm.py'}): profile 'myarm-pick-place' version "
        "2026-11-01: the home pose puts wrist_flex at 1.55 rad, outside its position limits [-1.5, 1.5] rad"]
    assert not (tmp_path / "out").exists()
