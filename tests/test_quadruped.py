"""The quadruped-turns cell: a stable gait, mirror-symmetric turns, and faults that show."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.embodiment import Profile, load_profile
from cellguard.errors import ProfileError, ScenarioError
from cellguard.policy.scripted_quadruped import ScriptedQuadrupedPolicy
from cellguard.robot.quadruped_cell import ASSETS, LEGS, QuadrupedTurns
from cellguard.robot.state import Observation
from cellguard.runtime import Run
from cellguard.scenario import parse_scenario

LEFT_JOINTS = [f"{leg}_{j}" for leg in ("fl", "rl") for j in ("abduction", "hip", "knee")]
WEAK_LEFT = {"kind": "servo_gain", "joint": LEFT_JOINTS, "factor": 0.8}


def _run(cycles: int, faults: list[dict] | None = None) -> Run:
    run = Run(parse_scenario({"cell": "quadruped-turns", "seed": 3, "acceptance_cycles": cycles,
                              "production_cycles": 0, "faults": faults or []}))
    for _ in range(cycles):
        run.cycle()
    return run


@pytest.fixture(scope="module")
def profile() -> Profile:
    return QuadrupedTurns().profile


@pytest.fixture(scope="module")
def gait(profile) -> ScriptedQuadrupedPolicy:
    return ScriptedQuadrupedPolicy(profile)


@pytest.fixture(scope="module")
def healthy() -> Run:
    return _run(4)


@pytest.fixture(scope="module")
def weak_left() -> Run:
    return _run(2, [WEAK_LEFT])


def _mismatch(left: dict, right: dict) -> float:
    """Relative difference of the yaw rates a turn and its mirror reached."""
    a, b = abs(left["yaw_rate_reached"]), abs(right["yaw_rate_reached"])
    return abs(a - b) / max(a, b)


# -- Model and profile ------------------------------------------------------------------------
def test_profile_pairs_every_joint_with_its_mirror(profile):
    assert profile.dof == 12
    paired = {p.left for p in profile.symmetry} | {p.right for p in profile.symmetry}
    assert paired == set(profile.joint_names)
    for pair in profile.symmetry:
        assert pair.sign == (-1.0 if pair.left.endswith("abduction") else 1.0)
        left, right = profile.joints[profile.index(pair.left)], profile.joints[profile.index(pair.right)]
        mirrored = sorted(pair.sign * np.array(left.position))
        assert mirrored == pytest.approx(right.position)  # a mirrored motion stays inside the limits


@pytest.mark.parametrize(("edit", "field"), [
    (lambda raw: raw["symmetry"][0].update(right="fr_elbow"), "symmetry[0].right"),
    (lambda raw: raw["symmetry"][1].update(sign=2), "symmetry[1].sign"),
    (lambda raw: raw["joints"]["rl_knee"].update(position=["-3.0 rad", "-0.5 rad"]), "joints.rl_knee.position"),
])
def test_profile_that_disagrees_with_the_model_is_refused(tmp_path, edit, field):
    raw = yaml.safe_load((ASSETS / "quadruped_profile.yaml").read_text())
    edit(raw)
    bad = tmp_path / "profile.yaml"
    bad.write_text(yaml.safe_dump(raw))
    with pytest.raises(ProfileError, match=re.escape(field)):
        load_profile(QuadrupedTurns().model, bad)


def test_cell_stands_and_steps_without_nan():
    cell = QuadrupedTurns()
    stand = cell.read().q
    cell.begin_cycle(0)
    for _ in range(500):
        cell.write(stand)
        cell.step()
    state = cell.read()
    for array in (state.q, state.qd, state.effort, state.current, cell.data.qpos, cell.data.qvel):
        assert np.isfinite(array).all()
    assert cell.data.qpos[2] > 0.25  # still standing at about its stance height
    assert np.abs(state.q - stand).max() < 0.1  # the knees sag a little under the weight


def test_power_off_drops_the_robot_and_the_next_cycle_stands_it_up(profile):
    cell = QuadrupedTurns()
    cell.begin_cycle(0)
    cell.set_power(False)  # a category 0 stop: torque off, joints braked
    for _ in range(1500):
        cell.step()
    assert cell.cycle_finished()
    outcome = cell.end_cycle()
    assert outcome["fallen"] and not outcome["success"]
    cell.set_power(True)
    cell.begin_cycle(1)
    assert cell.data.qpos[2] > 0.28
    np.testing.assert_allclose(cell.read().q, ScriptedQuadrupedPolicy(profile).stand)


# -- The gait ---------------------------------------------------------------------------------
def _chunk(policy: ScriptedQuadrupedPolicy, speed: float, yaw_rate: float, t_s: float) -> np.ndarray:
    """The chunk the gait answers ``t_s`` into a turn commanded at (speed, yaw_rate)."""
    policy.reset()
    command = {"speed_command": np.array([speed]), "yaw_rate_command": np.array([yaw_rate])}
    policy.infer(Observation(0, policy.stand, np.zeros(12), command))
    return policy.infer(Observation(round(t_s * 1e9), policy.stand, np.zeros(12), command)).actions


@settings(max_examples=30, deadline=None)
@given(speed=st.floats(0.0, 0.4), yaw_rate=st.floats(0.05, 1.0), t_s=st.floats(0.0, 3.0))
def test_right_turn_is_the_exact_mirror_of_the_left_turn(profile, gait, speed, yaw_rate, t_s):
    left, right = _chunk(gait, speed, yaw_rate, t_s), _chunk(gait, speed, -yaw_rate, t_s)
    names = profile.joint_names
    for pair in profile.symmetry:
        i, j = names.index(pair.left), names.index(pair.right)
        np.testing.assert_array_equal(right[:, j], pair.sign * left[:, i])
        np.testing.assert_array_equal(right[:, i], pair.sign * left[:, j])


def test_left_and_right_turns_are_different_motions(gait):
    assert np.abs(_chunk(gait, 0.25, 0.6, 0.7) - _chunk(gait, 0.25, -0.6, 0.7)).max() > 0.05


def test_gait_respects_the_profile_limits_so_the_guard_leaves_it_alone(healthy):
    profile, ticks = healthy.cell.profile, healthy.ticks
    dt = healthy.cell.dt_ns * 1e-9
    reference = ticks.rows("reference")
    np.testing.assert_allclose(ticks.rows("setpoint"), reference, atol=1e-9)
    assert (reference >= profile.q_min).all() and (reference <= profile.q_max).all()
    rates = np.diff(reference, axis=0) / dt
    for limit in ("velocity", "acceleration", "jerk"):
        assert (np.abs(rates).max(axis=0) < profile.array(limit)).all(), limit
        rates = np.diff(rates, axis=0) / dt


# -- Turns and their mirrors --------------------------------------------------------------------
def test_healthy_turns_alternate_and_succeed(healthy):
    cycles = healthy.cycles
    assert [c["direction"] for c in cycles] == ["left", "right", "left", "right"]
    for c in cycles:
        assert c["success"] and not c["fallen"] and not c["timed_out"]
        assert np.sign(c["yaw_rate_reached"]) == np.sign(c["yaw_rate_command"])
        assert abs(c["yaw_rate_ratio"] - 1.0) < 0.15
        assert c["cycle_time_s"] < 6.0
        for leg in LEGS:
            assert 0.5 < c[f"contact_duty.{leg}"] < 0.9  # a trot: each foot down a bit over half the time
            assert c[f"step_period_s.{leg}"] == pytest.approx(0.5, abs=0.03)


def test_healthy_mirrored_turns_match_within_5_percent(healthy):
    cycles = healthy.cycles
    for left, right in ((cycles[0], cycles[1]), (cycles[2], cycles[3])):
        assert _mismatch(left, right) < 0.05
        assert left["body_roll_rad"] == pytest.approx(-right["body_roll_rad"], abs=0.003)
        # A turn's front-left foot does what its mirror's front-right foot does.
        for leg, mirror in (("fl", "fr"), ("rl", "rr")):
            assert left[f"contact_duty.{leg}"] == pytest.approx(right[f"contact_duty.{mirror}"], abs=0.03)


def test_weak_left_servos_make_left_and_right_turns_differ(healthy, weak_left):
    left, right = weak_left.cycles
    assert left["direction"] == "left" and right["direction"] == "right"
    weak = _mismatch(left, right)
    assert weak > 0.05
    assert weak > 5 * _mismatch(*healthy.cycles[:2])
    # The weak side sags: the body rolls towards the left legs in both turns.
    assert left["body_roll_rad"] < 0 and right["body_roll_rad"] < 0


# -- Faults change the world ---------------------------------------------------------------------
def test_friction_growth_and_servo_gain_set_the_model():
    cell = QuadrupedTurns()
    sc = parse_scenario({"cell": "quadruped-turns", "faults": [
        {"kind": "friction_growth", "joint": "rr_knee", "from_cycle": 2, "per_cycle": 0.5}, WEAK_LEFT]})
    sc.check_against(cell)
    drives = cell.drives
    knee = cell.profile.index("rr_knee")
    for fault in sc.faults:
        fault.apply(cell, 3)
    assert cell.model.dof_frictionloss[drives.dadr[knee]] == pytest.approx(drives.nominal_frictionloss[knee] * 2.0)
    for joint in cell.profile.joint_names:
        i = cell.profile.index(joint)
        factor = 0.8 if joint in LEFT_JOINTS else 1.0
        assert cell.model.actuator_gainprm[drives.act[i], 0] == pytest.approx(drives.nominal_gain[i] * factor)
        assert cell.model.actuator_biasprm[drives.act[i], 1] == pytest.approx(drives.nominal_bias[i, 0] * factor)


def test_grown_friction_changes_the_gait(healthy):
    worn = Run(parse_scenario({"cell": "quadruped-turns", "seed": 3, "acceptance_cycles": 1, "production_cycles": 0}))
    worn.cell.set_friction_scale("fl_knee", 10.0)  # friction_growth at per_cycle 1.0, nine cycles on
    faulted, good = worn.cycle(), healthy.cycles[0]
    assert faulted["features"]["tracking_max.fl_knee"] > good["features"]["tracking_max.fl_knee"] + 0.005
    assert abs(faulted["yaw_rate_reached"]) < abs(good["yaw_rate_reached"]) - 0.01


@pytest.mark.parametrize("fault", [{"kind": "policy_latency", "at_cycle": 0, "ms": 150},
                                   {"kind": "policy_nan", "at_cycle": 0}])
def test_policy_faults_change_the_turn(healthy, fault):
    run = _run(1, [fault])
    faulted, good = run.cycles[0], healthy.cycles[0]
    assert faulted["yaw_rate_reached"] != good["yaw_rate_reached"]
    if fault["kind"] == "policy_latency":
        assert faulted["features"]["latency_mean_ms"] > good["features"]["latency_mean_ms"] + 100
    else:
        assert any(e.kind == "chunk_rejected" for e in run.events)


def test_arm_only_faults_are_refused():
    sc = parse_scenario({"cell": "quadruped-turns", "faults": [{"kind": "fixture_shift", "at_cycle": 0, "dx_mm": 2}]})
    with pytest.raises(ScenarioError, match=r"faults\[0\].kind"):
        Run(sc)


# -- Through the command line ----------------------------------------------------------------------
def test_cli_runs_the_quadruped_scenario(tmp_path):
    raw = yaml.safe_load((ASSETS.parent.parent / "scenarios" / "quadruped.yaml").read_text())
    raw.update(acceptance_cycles=1, production_cycles=1, faults=[])  # its fault (cycle 16) is past these two
    scenario = tmp_path / "quadruped.yaml"
    scenario.write_text(yaml.safe_dump(raw))
    result = CliRunner().invoke(app, ["run", str(scenario), "--out", str(tmp_path / "out"), "--json"])
    assert result.exit_code == 0, result.output
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert [c["direction"] for c in summary["cycles"]] == ["left", "right"]
    assert all(c["success"] for c in summary["cycles"])
    features = summary["cycles"][0]["features"]
    assert {"yaw_rate_reached", "contact_duty.fl", "touchdown_lag_s.rr", "current_rms.fl_knee"} <= set(features)
