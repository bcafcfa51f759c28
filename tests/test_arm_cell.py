"""The arm cell end to end through the tick path: success, drift absorbed, large faults felt."""

from __future__ import annotations

import numpy as np
import pytest

from cellguard.runtime import Run
from cellguard.scenario import parse_scenario


def _run(cycles: int, faults: list[dict] | None = None, seed: int = 3) -> Run:
    run = Run(parse_scenario({"cell": "arm-pick-place", "seed": seed, "acceptance_cycles": cycles,
                              "production_cycles": 0, "faults": faults or []}))
    for _ in range(cycles):
        run.cycle()
    return run


@pytest.fixture(scope="module")
def healthy() -> Run:
    return _run(8)


def test_healthy_cell_succeeds_and_stays_finite(healthy):
    rates = [c["success"] for c in healthy.cycles]
    assert np.mean(rates) >= 0.95
    for c in healthy.cycles:
        assert not c["timed_out"] and 3.0 < c["cycle_time_s"] < 6.0
        assert all(np.isfinite(v) for v in c["features"].values())
    assert healthy.events == []


def test_current_follows_effort_over_torque_constant(arm):
    arm.write(arm.read().q + np.array([0.0, 0.1, 0.0, 0.0, 0.0, 0.0]))
    for _ in range(50):
        arm.step()
    state = arm.read()
    kt = arm.profile.array("torque_constant")
    assert abs(state.effort[1]) > 1.0
    np.testing.assert_allclose(state.current, state.effort / kt, atol=0.05)


def test_small_fixture_shift_is_absorbed_but_moves_the_grasp_pose(healthy):
    shifted = _run(4, [{"kind": "fixture_shift", "at_cycle": 0, "dx_mm": 2.0}])
    assert all(c["success"] for c in shifted.cycles)
    base = np.mean([c["features"]["grasp_tcp_x_mm"] for c in healthy.cycles])
    moved = np.mean([c["features"]["grasp_tcp_x_mm"] for c in shifted.cycles])
    assert moved - base == pytest.approx(2.0, abs=0.4)


@pytest.mark.parametrize("fault", [
    {"kind": "fixture_shift", "at_cycle": 0, "dx_mm": 6.0},
    {"kind": "camera_shift", "at_cycle": 0, "dx_mm": 5.0},
])
def test_large_shift_makes_grasps_fail(fault):
    run = _run(3, [fault])
    assert np.mean([c["success"] for c in run.cycles]) <= 0.5
    assert all(c["grasp_time_s"] > 0 for c in run.cycles)  # the fingers closed, beside the part


def test_camera_sees_the_fixture_move_but_not_its_own_move(healthy):
    fixture = _run(1, [{"kind": "fixture_shift", "at_cycle": 0, "dx_mm": 4.0}]).cycles[0]["features"]
    camera = _run(1, [{"kind": "camera_shift", "at_cycle": 0, "dx_mm": 4.0}]).cycles[0]["features"]
    base = np.mean([c["features"]["fixture_seen_x_mm"] for c in healthy.cycles])
    assert fixture["fixture_seen_x_mm"] - base == pytest.approx(4.0, abs=0.5)
    assert camera["fixture_seen_x_mm"] - base == pytest.approx(-4.0, abs=0.5)
