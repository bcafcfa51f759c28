"""Every fault kind changes the simulated world (or the policy channel) it claims to change."""

from __future__ import annotations

import numpy as np
import pytest

from cellguard.robot.arm_cell import ArmPickPlace
from cellguard.robot.faults import FAULTS
from cellguard.runtime import Run
from cellguard.scenario import parse_scenario


def _fault(spec: dict):
    return parse_scenario({"cell": "arm-pick-place", "faults": [spec]}).faults[0]


def test_registry_covers_the_design_kinds():
    assert set(FAULTS) == {"fixture_shift", "friction_growth", "servo_gain", "camera_shift", "tool_slip",
                           "policy_latency", "policy_nan", "friction_step", "intermittent_slip", "part_misplaced",
                           "late_recovery"}


@pytest.mark.parametrize(("spec", "read"), [
    ({"kind": "fixture_shift", "at_cycle": 2, "dx_mm": 4.0, "dy_mm": -1.0},
     lambda c: c.data.mocap_pos[0] - c.nominal["fixture"]),
    ({"kind": "camera_shift", "at_cycle": 2, "dx_mm": 4.0, "dy_mm": -1.0},
     lambda c: c.data.mocap_pos[1] - c.nominal["camera"]),
    ({"kind": "tool_slip", "at_cycle": 2, "dx_mm": 4.0, "dy_mm": -1.0},
     lambda c: c.model.body_pos[c._tool_body] - c.nominal["tool"]),
])
def test_offset_faults_start_at_their_cycle(spec, read):
    cell, fault = ArmPickPlace(), _fault(spec)
    fault.apply(cell, 1)
    np.testing.assert_allclose(read(cell), 0.0)
    fault.apply(cell, 2)
    np.testing.assert_allclose(read(cell)[:2], [0.004, -0.001])


def test_friction_grows_per_cycle():
    cell, fault = ArmPickPlace(), _fault({"kind": "friction_growth", "joint": "elbow", "from_cycle": 10, "per_cycle": 0.1})
    i = cell.profile.index("elbow")
    nominal = cell.drives.nominal_frictionloss[i]
    fault.apply(cell, 9)
    assert cell.model.dof_frictionloss[cell._dadr[i]] == pytest.approx(nominal)
    fault.apply(cell, 14)
    assert cell.model.dof_frictionloss[cell._dadr[i]] == pytest.approx(nominal * 1.5)


def test_servo_gain_scales_stiffness_and_damping():
    cell, fault = ArmPickPlace(), _fault({"kind": "servo_gain", "joint": "shoulder_lift", "factor": 0.85})
    fault.apply(cell, 0)
    a = cell.drives.act[cell.profile.index("shoulder_lift")]
    assert cell.model.actuator_gainprm[a, 0] == pytest.approx(400 * 0.85)
    assert cell.model.actuator_biasprm[a, 1] == pytest.approx(-400 * 0.85)


def _one_cycle(faults: list[dict]) -> Run:
    run = Run(parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 0,
                              "faults": faults}))
    run.cycle()
    return run


def test_policy_latency_makes_chunks_late():
    run = _one_cycle([{"kind": "policy_latency", "at_cycle": 0, "ms": 250}])
    f = run.cycles[0]["features"]
    assert f["latency_mean_ms"] == pytest.approx(260.0)
    assert f["stale_chunks"] > 0


def test_policy_nan_is_rejected_not_executed():
    run = _one_cycle([{"kind": "policy_nan", "at_cycle": 0}])
    assert [e.kind for e in run.events] == ["chunk_rejected"]
    assert "non-finite" in run.events[0].reason
    assert run.cycles[0]["success"]


@pytest.mark.parametrize("kind", ["intermittent_slip", "part_misplaced"])
def test_intermittent_faults_hit_about_their_rate_and_replay(kind):
    fault = _fault({"kind": kind, "at_cycle": 10, "rate": 0.2, "seed": 3, "dx_mm": 2.0})
    cell = ArmPickPlace()
    read = ((lambda: cell.model.body_pos[cell._tool_body] - cell.nominal["tool"]) if kind == "intermittent_slip"
            else (lambda: cell._part_offset))
    hit = []
    for cycle in range(400):
        fault.apply(cell, cycle)
        hit.append(bool(np.abs(read()).max() > 0))
        if hit[-1]:
            np.testing.assert_allclose(read()[:2], [0.002, 0.0])
    assert not any(hit[:10]) and abs(np.mean(hit[10:]) - 0.2) < 0.05
    again = []
    for cycle in range(400):
        fault.apply(cell, cycle)
        again.append(bool(np.abs(read()).max() > 0))
    assert again == hit


def test_a_misplaced_part_is_presented_off_its_datum():
    cell = ArmPickPlace()
    cell.begin_cycle(0)
    nominal = cell.data.xpos[cell._part_body].copy()
    cell.set_part_offset(np.array([0.002, 0.0, 0.0]))
    cell.begin_cycle(1)
    assert cell.data.xpos[cell._part_body][0] - nominal[0] == pytest.approx(0.002, abs=1e-3)


def test_friction_step_is_a_constant_multiple():
    cell, fault = ArmPickPlace(), _fault({"kind": "friction_step", "joint": "elbow", "at_cycle": 3, "factor": 1.5})
    i = cell.profile.index("elbow")
    nominal = cell.drives.nominal_frictionloss[i]
    fault.apply(cell, 2)
    assert cell.model.dof_frictionloss[cell._dadr[i]] == pytest.approx(nominal)
    for cycle in (3, 30):
        fault.apply(cell, cycle)
        assert cell.model.dof_frictionloss[cell._dadr[i]] == pytest.approx(nominal * 1.5)


def test_changes_of_one_setting_compose_and_none_wipes_out_another():
    """Each fault set its setting outright, its 'off' value included: a second fixture shift, not yet started,
    put the first one back to 0 mm, and a warm-up reset a growing friction to its own factor."""
    from cellguard.robot.world_changes import apply_world_changes

    scenario = parse_scenario({"cell": "arm-pick-place", "faults": [
        {"kind": "fixture_shift", "at_cycle": 0, "dx_mm": 8.0},
        {"kind": "fixture_shift", "at_cycle": 1, "dx_mm": 8.0},
        {"kind": "friction_growth", "joint": "elbow", "from_cycle": 10, "per_cycle": 0.02},
        {"kind": "servo_gain", "joint": "elbow", "factor": 0.5},
        {"kind": "servo_gain", "joint": "elbow", "factor": 0.8}],
        "process_changes": [{"kind": "warmup", "at_cycle": 50, "friction": 0.5, "cycles": 4.0}]})
    cell = ArmPickPlace(seed=0)
    changes = [*scenario.faults, *scenario.process_changes]
    fixture = lambda: (cell.data.mocap_pos[0] - cell.nominal["fixture"])[0] * 1e3  # noqa: E731 [mm]
    apply_world_changes(cell, changes, 0)
    assert fixture() == pytest.approx(8.0)  # the second shift, not started, left the first in place
    apply_world_changes(cell, changes, 1)
    assert fixture() == pytest.approx(16.0)
    elbow = cell.profile.index("elbow")
    drives = cell.drives
    friction = lambda: cell.model.dof_frictionloss[drives.dadr[elbow]] / drives.nominal_frictionloss[elbow]  # noqa: E731
    apply_world_changes(cell, changes, 50)
    assert friction() == pytest.approx((1.0 + 0.02 * 41) * 1.5)  # grown friction x the cold restart's
    apply_world_changes(cell, changes, 79)
    assert friction() == pytest.approx((1.0 + 0.02 * 70) * (1.0 + 0.5 * np.exp(-29 / 4.0)))
    gain = cell.model.actuator_gainprm[cell.drives.act[elbow], 0] / cell.drives.nominal_gain[elbow]
    assert gain == pytest.approx(0.4)


def test_a_joint_listed_twice_in_one_fault_is_refused():
    """servo_gain on [elbow, elbow] scaled the gain twice (0.25 for 0.5) while the ground truth said 0.5."""
    from cellguard.errors import ScenarioError

    with pytest.raises(ScenarioError, match=r"faults\[0\].*a joint is listed twice"):
        parse_scenario({"cell": "arm-pick-place", "faults": [{"kind": "servo_gain", "joint": ["elbow", "elbow"],
                                                              "factor": 0.5}]})
