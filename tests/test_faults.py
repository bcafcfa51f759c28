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
                           "policy_latency", "policy_nan"}


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
