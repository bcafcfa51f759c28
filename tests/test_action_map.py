"""ActionMap: load-time checks name the problem; mapping round-trips; end-effector targets via mink IK."""

import copy
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cellguard.errors import ConfigError
from cellguard.embodiment.action_map import identity_map, parse_action_map
from cellguard.robot.arm_cell import ArmPickPlace

# A policy trained on another arm: its own joint order, degrees and millimetres, one flipped axis,
# an offset zero, and a gripper command normalised to [0, 1].
FOREIGN = {
    "robot": "arm-pick-place",
    "actions": [
        {"name": "gripper", "joint": "gripper", "unit": "1", "scale": "23 mm", "offset": "6 mm"},
        {"name": "wrist_roll.pos", "joint": "wrist_roll", "unit": "deg"},
        {"name": "wrist_flex.pos", "joint": "wrist_flex", "unit": "deg", "offset": "0.2 rad"},
        {"name": "elbow.pos", "joint": "elbow", "unit": "deg", "sign": -1},
        {"name": "shoulder_lift.pos", "joint": "shoulder_lift", "unit": "rad"},
        {"name": "shoulder_pan.pos", "joint": "shoulder_pan", "unit": "deg", "sign": -1, "offset": "10 deg"},
    ],
}


_CELL = ArmPickPlace()  # hypothesis tests cannot take function-scoped fixtures


@pytest.fixture(scope="module")
def cell():
    return _CELL


def test_foreign_map_converts_order_units_signs_offsets_and_gripper_scale(cell):
    amap = parse_action_map(FOREIGN, cell.profile)
    policy = np.array([[0.5, 90.0, 10.0, -100.0, 0.3, 20.0]])
    q = amap.to_robot(policy, cell.q_home)[0]
    i = cell.profile.index
    assert q[i("gripper")] == pytest.approx(0.006 + 0.5 * 0.023)
    assert q[i("wrist_roll")] == pytest.approx(math.pi / 2)
    assert q[i("wrist_flex")] == pytest.approx(0.2 + math.radians(10.0))
    assert q[i("elbow")] == pytest.approx(math.radians(100.0))
    assert q[i("shoulder_lift")] == pytest.approx(0.3)
    assert q[i("shoulder_pan")] == pytest.approx(math.radians(10.0) - math.radians(20.0))


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(0.0, 1.0), min_size=6, max_size=6))
def test_state_to_policy_and_back_is_identity(fractions):
    cell = _CELL
    amap = parse_action_map(FOREIGN, cell.profile)
    q = cell.profile.q_min + np.array(fractions) * (cell.profile.q_max - cell.profile.q_min)
    back = amap.to_robot(amap.to_policy_state(q)[None, :], np.zeros(6))[0]
    np.testing.assert_allclose(back, q, atol=1e-12)


def test_identity_map_passes_actions_through(cell):
    amap = identity_map(cell.profile)
    actions = np.random.default_rng(0).normal(size=(5, 6))
    np.testing.assert_array_equal(amap.to_robot(actions, cell.q_home), actions)


_EE_MAP = {"robot": "arm-pick-place",
           "actions": [{"name": "ee.x", "ee": "x", "unit": "m"}, {"name": "ee.y", "ee": "y", "unit": "m"},
                       {"name": "ee.z", "ee": "z", "unit": "m"}, {"name": "wrist_roll", "joint": "wrist_roll",
                                                                  "unit": "rad"},
                       {"name": "gripper", "joint": "gripper", "unit": "m"}],
           "ik": {"site": "tcp", "joints": ["shoulder_pan", "shoulder_lift", "elbow", "wrist_flex"]}}


def _without(entry_name: str) -> dict:
    return {**FOREIGN, "actions": [a for a in FOREIGN["actions"] if a["name"] != entry_name]}


@pytest.mark.parametrize(
    ("raw", "message"),
    [
        (_without("wrist_roll.pos"), "joint 'wrist_roll' is not mapped"),
        ({**FOREIGN, "robot": "so100"}, "robot: the map is for 'so100'"),
        ({**FOREIGN, "actions": [*FOREIGN["actions"][:5], {"name": "p", "joint": "shoulder_pan", "unit": "mm"}]},
         "actions[5].unit: unit 'mm' does not fit"),
        ({**FOREIGN, "actions": [{"name": "g", "joint": "gripper", "unit": "deg"}, *FOREIGN["actions"][1:]]},
         "actions[0].unit: unit 'deg' does not fit"),
        ({**FOREIGN, "actions": [{"name": "g", "joint": "gripper", "unit": "1"}, *FOREIGN["actions"][1:]]},
         "actions[0].scale: a dimensionless action"),
        ({**FOREIGN, "actions": [*FOREIGN["actions"], {"name": "x", "joint": "knee", "unit": "rad"}]},
         "actions[6].joint: 'knee' is not a joint"),
        ({**FOREIGN, "actions": [*FOREIGN["actions"], {"name": "e2", "joint": "elbow", "unit": "rad"}]},
         "actions[6].joint: 'elbow' is already driven"),
        ({**FOREIGN, "actions": [*FOREIGN["actions"][:5], {"name": "p", "joint": "shoulder_pan", "unit": "rad", "sign": 2}]},
         "actions[5].sign"),
        ({**_without("wrist_roll.pos"), "hold": {"wrist_roll": "9 rad"}}, "hold.wrist_roll: 9 rad lies outside"),
        ({**FOREIGN, "extra": 1}, "extra: unknown key"),
        ({**FOREIGN, "actions": [*FOREIGN["actions"], {"name": "ee.x", "ee": "x", "unit": "mm"}]},
         "ik: end-effector actions need an ik section"),
        # a name is printed in errors and records: an escape code in it recoloured the terminal
        ({**FOREIGN, "actions": [{**FOREIGN["actions"][0], "name": "grip\x1b[2J"}, *FOREIGN["actions"][1:]]},
         r"actions[0].name: 'grip\\x1b[2J' holds control characters"),
        ({**FOREIGN, "actions": [{**FOREIGN["actions"][0], "name": "grip\n"}, *FOREIGN["actions"][1:]]},
         r"actions[0].name: 'grip\\n' holds control characters"),
        # an offset in the wrong unit put the joint far outside its limits: every chunk was rejected at run time
        ({**FOREIGN, "actions": [{**FOREIGN["actions"][0], "offset": "1000 m"}, *FOREIGN["actions"][1:]]},
         "actions[0].offset: 1000 m puts gripper at 1000 m where the policy outputs 0, more than 0.023 m outside"),
        ({**FOREIGN, "actions": [*FOREIGN["actions"][:5], {**FOREIGN["actions"][5], "offset": "1000 deg"}]},
         "actions[5].offset: 1000 deg puts shoulder_pan at 17.45 rad .* more than 6.283 rad outside"),
        ({**_EE_MAP, "ik": {**_EE_MAP["ik"], "joints": ["shoulder_pan", "shoulder_lift", "elbow", "wrist_flex",
                                                        "elbow"]}},
         "ik.joints[4]: 'elbow' is listed twice"),
    ],
)
def test_bad_maps_are_refused_naming_the_problem(cell, raw, message):
    with pytest.raises(ConfigError, match=message.replace("[", r"\[").replace("]", r"\]").replace("(", r"\(")):
        parse_action_map(raw, cell.profile)


def test_dimension_and_name_mismatch_with_the_policy_is_named(cell):
    amap = parse_action_map(FOREIGN, cell.profile)
    with pytest.raises(ConfigError, match="outputs 7 actions per step, the map declares 6"):
        amap.check_policy(7, None, "onnx:x.onnx")
    names = ("gripper", "wrist_roll.pos", "wrist_flex.pos", "elbow.pos", "pan", "shoulder_pan.pos")
    with pytest.raises(ConfigError, match=r"actions\[4\].name is 'shoulder_lift.pos' but onnx:x.onnx calls action 4 'pan'"):
        amap.check_policy(6, names, "onnx:x.onnx")


def test_end_effector_targets_reach_their_positions_through_mink_ik(cell):
    from cellguard.policy.ik import IkSolver

    raw = {"robot": "arm-pick-place",
           "actions": [{"name": "ee.x", "ee": "x", "unit": "mm"}, {"name": "ee.y", "ee": "y", "unit": "mm"},
                       {"name": "ee.z", "ee": "z", "unit": "mm"}, {"name": "grip", "joint": "gripper", "unit": "mm"}],
           "hold": {"wrist_roll": "0 rad"},
           "ik": {"site": "tcp", "joints": ["shoulder_pan", "shoulder_lift", "elbow", "wrist_flex"]}}
    amap = parse_action_map(raw, cell.profile)
    solver = IkSolver(copy.deepcopy(cell.model), cell.profile, amap.ik)
    start = solver.pose(cell.q_home)
    goal = np.array([0.30, 0.10, 0.05])
    path = start[:3] + np.linspace(0.0, 1.0, 20)[:, None] * (goal - start[:3])
    actions = np.hstack([path * 1e3, np.full((20, 1), 20.0)])
    q = amap.to_robot(actions, cell.q_home, solver)
    assert q[:, cell.profile.index("gripper")] == pytest.approx(0.020)
    assert (q >= cell.profile.q_min).all() and (q <= cell.profile.q_max).all()
    reached = np.array([solver.pose(row)[:3] for row in q])
    assert np.abs(reached - path).max() < 5e-4  # [m]
    # The tool axis stays pointing down (only its spin is free): roll stays at pi.
    tilt = [abs(abs(solver.pose(row)[3]) - math.pi) for row in q]
    assert max(tilt) < 0.02
    # The state goes back to the policy's space as the same end-effector position, in mm.
    np.testing.assert_allclose(amap.to_policy_state(q[-1], solver)[:3], path[-1] * 1e3, atol=0.5)


def test_delta_mode_moves_relative_to_the_current_pose(cell):
    from cellguard.policy.ik import IkSolver

    raw = {"robot": "arm-pick-place",
           "actions": [{"name": "dz", "ee": "z", "unit": "mm"}, {"name": "grip", "joint": "gripper", "unit": "m"}],
           "hold": {"wrist_roll": "0 rad"},
           "ik": {"site": "tcp", "joints": ["shoulder_pan", "shoulder_lift", "elbow", "wrist_flex"], "mode": "delta"}}
    amap = parse_action_map(raw, cell.profile)
    solver = IkSolver(copy.deepcopy(cell.model), cell.profile, amap.ik)
    start = solver.pose(cell.q_home)
    q = amap.to_robot(np.array([[-30.0, 0.02]]), cell.q_home, solver)[0]
    np.testing.assert_allclose(solver.pose(q)[:3], start[:3] + [0.0, 0.0, -0.030], atol=5e-4)



@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_a_non_finite_end_effector_target_makes_that_step_non_finite_never_a_hold(cell, bad):
    """Unmapped axes were marked NaN and held as now, so the policy's own NaN on ee.x held the pose silently."""
    from cellguard.policy.ik import IkSolver

    amap = parse_action_map(_EE_MAP, cell.profile)
    solver = IkSolver(copy.deepcopy(cell.model), cell.profile, amap.ik)
    start = solver.pose(cell.q_home)
    row = [*start[:3], 0.0, 0.02]
    actions = np.array([row, row, row])
    actions[1, 0] = bad
    q = amap.to_robot(actions, cell.q_home, solver)
    ik = list(solver.joint_index)
    assert np.isfinite(q[[0, 2]]).all()
    assert np.isnan(q[1, ik]).all()


def test_a_policy_nan_on_an_end_effector_action_is_a_rejected_chunk_in_a_run(cell):
    from cellguard.policy.adapter import MappedPolicy
    from cellguard.runtime import Run
    from cellguard.scenario import parse_scenario

    class NanX:
        action_dim, action_names, embedded_map = 5, None, None

        def infer(self, inputs):
            return np.tile([math.nan, 0.0, 0.19, 0.0, 0.025], (25, 1))

        def reset(self):
            pass

        def content_hash(self):
            return "0" * 64

    def factory():
        arm = ArmPickPlace()
        return MappedPolicy(NanX(), parse_action_map(_EE_MAP, arm.profile), arm, "test:nan-x", 0.02)

    run = Run(parse_scenario({"cell": "arm-pick-place", "seed": 3, "acceptance_cycles": 1, "production_cycles": 0}),
              policy_factory=factory)
    home = run.cell.read().q
    run.cycle()
    rejected = [e for e in run.events if e.kind == "chunk_rejected"]
    assert rejected and "non-finite" in rejected[0].reason
    assert np.abs(run.cell.read().q - home).max() < 0.01


@settings(max_examples=200, deadline=None)
@given(st.text(min_size=1, max_size=12))
def test_any_action_name_is_accepted_only_when_printable(name):
    cell = _CELL
    raw = {**FOREIGN, "actions": [{**FOREIGN["actions"][0], "name": name}, *FOREIGN["actions"][1:]]}
    try:
        amap = parse_action_map(raw, cell.profile)
    except ConfigError as exc:
        assert "\n" not in str(exc)
    else:
        assert amap.names[0].isprintable()


@pytest.mark.parametrize("names", [tuple(a["name"] for a in FOREIGN["actions"][:5]),
                                   (*(a["name"] for a in FOREIGN["actions"]), "extra")])
def test_a_names_list_of_another_length_than_the_output_is_refused_naming_both_counts(cell, names):
    """Compared pairwise up to the shorter list, 5 or 7 names for 6 outputs were accepted."""
    amap = parse_action_map(FOREIGN, cell.profile)
    with pytest.raises(ConfigError, match=rf"onnx:x.onnx names {len(names)} actions but outputs 6 per step, and "
                                          r"the map declares 6"):
        amap.check_policy(6, names, "onnx:x.onnx")
