"""Profile fields that loaded although no robot could run them: a symmetry pair whose mirror leaves the other joint's
range (every mirrored chunk refused), a position range of a joint the model leaves unlimited with no plausible bound
(+-1e308 rad made the guard's soft limits [inf, -inf]), and a ``measured`` or ``symmetry`` list written as false, 0,
"" or {} (taken as none)."""

from __future__ import annotations

import mujoco
import pytest

from cellguard.embodiment.profile import parse_profile
from cellguard.errors import ProfileError
from cellguard.robot.arm_cell import ASSETS, load_model

QUADRUPED = (ASSETS / "quadruped_profile.yaml").read_text()
KNEES = "{left: fl_knee,      right: fr_knee,      sign: 1}"
ARM = (ASSETS / "arm_profile.yaml").read_text()


def _quadruped(text: str):
    return parse_profile(mujoco.MjModel.from_xml_path(str(ASSETS / "quadruped.xml")), text.encode(), "q.yaml")


def test_a_symmetry_pair_whose_mirror_leaves_the_other_joints_range_is_refused():
    """Both knees range over [-2.6, -0.5] rad; sign -1 mirrors every angle of one outside the other's: the run
    rejected 66 chunks and ended in a watchdog stop, exit 0."""
    assert KNEES in QUADRUPED
    with pytest.raises(ProfileError, match=r"^q.yaml: symmetry\[2\]: fr_knee = -1 \* fl_knee puts fr_knee in "
                                           r"\[0.5, 2.6\], outside its range \[-2.6, -0.5\] for every position of "
                                           r"fl_knee; check the sign$"):
        _quadruped(QUADRUPED.replace(KNEES, KNEES.replace("sign: 1", "sign: -1")))


def test_mirrors_whose_ranges_overlap_load():
    """The packaged quadruped: abduction mirrored with sign -1 over a range symmetric about zero, hip and knee +1."""
    pairs = [(p.left, p.sign) for p in _quadruped(QUADRUPED).symmetry]
    assert pairs[:3] == [("fl_abduction", -1.0), ("fl_hip", 1.0), ("fl_knee", 1.0)]


UNLIMITED = """<mujoco><worldbody><body name="b"><joint name="roll" type="hinge" limited="false"/>
<geom size="0.1" mass="1"/></body></worldbody></mujoco>"""


def _roll(position: str):
    text = (f'robot: x\nversion: "1"\njoints:\n  roll: {{position: {position}, velocity: "3 rad/s", '
            'acceleration: "15 rad/s^2", jerk: "1000 rad/s^3", effort: "5 N*m", torque_constant: "1 N*m/A"}\n')
    return parse_profile(mujoco.MjModel.from_xml_string(UNLIMITED), text.encode(), "roll.yaml")


@pytest.mark.parametrize("position", ['["-1e308 rad", "1e308 rad"]', '["0 rad", "1e5 rad"]', '["-2e4 rad", "0 rad"]'])
def test_a_position_range_beyond_any_joints_is_refused_where_the_model_sets_none(position):
    with pytest.raises(ProfileError, match=r"^roll.yaml: joints.roll.position: \[.*\] reaches beyond the plausible "
                                           r"\+-10000 rad; no joint travels that far"):
        _roll(position)


def test_a_multi_turn_range_of_an_unlimited_joint_still_loads():
    assert _roll('["-100 rad", "100 rad"]').joints[0].position == (-100.0, 100.0)


@pytest.mark.parametrize("key", ["measured", "symmetry"])
@pytest.mark.parametrize("written, kind", [("false", "bool"), ("0", "int"), ('""', "str"), ("{}", "dict")])
def test_a_list_written_as_false_zero_or_empty_text_or_mapping_is_refused(key, written, kind):
    head, tail = ARM.split(f"\n{key}:", 1)
    rest = tail[tail.index("\n") + 1:]
    if key == "measured":
        rest = rest[rest.index("symmetry:"):]
    text = f"{head}\n{key}: {written}\n{rest}"
    with pytest.raises(ProfileError, match=rf"^p.yaml: {key}: expected a list, got {kind}$"):
        parse_profile(load_model(), text.encode(), "p.yaml")


def test_a_list_left_empty_is_none():
    profile = parse_profile(load_model(), ARM.replace("symmetry: []", "symmetry:").encode(), "p.yaml")
    assert profile.symmetry == ()
