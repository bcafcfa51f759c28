"""IK: a target the site cannot reach refuses the chunk, naming the step, the target and the miss.

An unreachable target (2 m out) gave chunks whose shoulder flipped between two solutions every
step while the tool moved away from it: 801 tracker_failed and no event naming the IK.
"""

import copy

import numpy as np
import pytest

from cellguard.embodiment.action_map import parse_action_map
from cellguard.policy.adapter import InferenceError, MappedPolicy
from cellguard.policy.ik import IkSolver
from cellguard.robot.arm_cell import ArmPickPlace
from cellguard.runtime import Run
from cellguard.scenario import parse_scenario

XYZ_MAP = {"robot": "arm-pick-place",
           "actions": [{"name": "x", "ee": "x", "unit": "mm"}, {"name": "y", "ee": "y", "unit": "mm"},
                       {"name": "z", "ee": "z", "unit": "mm"}, {"name": "g", "joint": "gripper", "unit": "mm"}],
           "hold": {"wrist_roll": "0 rad"},
           "ik": {"site": "tcp", "joints": ["shoulder_pan", "shoulder_lift", "elbow", "wrist_flex"],
                  "mode": "absolute"}}
FAR, NEAR = (2000.0, 40.0, 150.0, 20.0), (180.0, 40.0, 150.0, 20.0)  # [mm]


@pytest.fixture(scope="module")
def arm():
    cell = ArmPickPlace()
    amap = parse_action_map(XYZ_MAP, cell.profile)
    return cell, amap, IkSolver(copy.deepcopy(cell.model), cell.profile, amap.ik)


def test_an_unreachable_target_refuses_the_chunk_naming_step_target_and_miss(arm):
    cell, amap, solver = arm
    with pytest.raises(InferenceError, match=r"IK: step 0: target \(2000.0, 40.0, 150.0\) mm for site 'tcp' not "
                                             r"reached from the current pose: the solve ends \d+\.\d mm away "
                                             r"\(tolerance 1 mm; out of reach, or only reached from another joint "
                                             r"configuration\)"):
        amap.to_robot(np.tile(FAR, (10, 1)), cell.q_home, solver)


def test_a_target_reached_only_from_another_configuration_is_not_called_out_of_reach(arm):
    """The tool point with the base turned 2.4 rad (inside its limits) is not found from home, a local minimum:
    the refusal said "out of reach", and the operator looked for a workspace fault that was not there."""
    cell, amap, solver = arm
    turned = cell.q_home.copy()
    turned[cell.profile.index("shoulder_pan")] = 2.4
    target = [*(solver.pose(turned)[:3] * 1e3), 20.0]
    with pytest.raises(InferenceError, match=r"not reached from the current pose") as refused:
        amap.to_robot(np.array([target]), cell.q_home, solver)
    assert "out of reach:" not in str(refused.value)
    start = cell.q_home.copy()
    start[cell.profile.index("shoulder_pan")] = 2.3
    reached = amap.to_robot(np.array([target]), start, solver)[0]
    assert np.linalg.norm(solver.pose(reached)[:3] * 1e3 - target[:3]) < 1.0  # [mm] reachable from nearby


def test_the_first_unreachable_step_of_a_chunk_is_the_one_named(arm):
    cell, amap, solver = arm
    chunk = np.array([NEAR, NEAR, NEAR, FAR, NEAR])
    with pytest.raises(InferenceError, match=r"step 3: target \(2000.0"):
        amap.to_robot(chunk, cell.q_home, solver)


def test_a_reachable_target_is_reached_by_every_step_with_one_solution(arm):
    cell, amap, solver = arm
    q = amap.to_robot(np.tile(NEAR, (10, 1)), cell.q_home, solver)
    reached = np.array([solver.pose(row)[:3] for row in q])
    assert np.abs(reached - np.array(NEAR[:3]) * 1e-3).max() < 1e-3  # [m] the stated tolerance
    assert np.ptp(q, axis=0).max() < 1e-3  # [rad] the same solution every step, no alternation


def test_in_a_run_an_unreachable_target_is_a_named_failure_and_the_arm_holds():
    class Far:
        action_dim, action_names, embedded_map = 4, None, None

        def infer(self, inputs):
            return np.tile(FAR, (25, 1))

        def reset(self):
            pass

        def content_hash(self):
            return "0" * 64

    def factory():
        cell = ArmPickPlace()
        return MappedPolicy(Far(), parse_action_map(XYZ_MAP, cell.profile), cell, "test:far", 0.02)

    run = Run(parse_scenario({"cell": "arm-pick-place", "seed": 3, "acceptance_cycles": 1, "production_cycles": 0}),
              policy_factory=factory)
    home = run.cell.read().q
    run.cycle()
    failed = [e for e in run.events if e.kind == "inference_failed"]
    assert failed and "IK: step 0: target (2000.0, 40.0, 150.0) mm" in failed[0].reason
    assert not [e for e in run.events if e.kind == "tracker_failed"]
    assert np.abs(run.cell.read().q - home).max() < 0.01
