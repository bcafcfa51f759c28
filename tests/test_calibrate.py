"""Excitation through the guarded loop, and identification of hidden physics from its record."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from cellguard.calibrate.bootstrap import simulate
from cellguard.calibrate.excitation import MARGIN, ExcitationPolicy, excitation_scenario, excite
from cellguard.calibrate.identify import CalibrationError, identify, load_segments, parse_params
from cellguard.cli import app
from cellguard.record.reader import open_record
from cellguard.robot.physics import Physics
from cellguard.robot.registry import make_cell
from cellguard.runtime.loop import Run, run_scenario

ARM = "arm-pick-place"
HIDDEN = Physics(friction={"shoulder_lift": 1.5, "elbow": 1.5}, armature=0.7, delay_s=0.004)
runner = CliRunner()


@pytest.fixture(scope="module")
def nominal_record(tmp_path_factory):
    out = tmp_path_factory.mktemp("excite") / "nominal"
    summary = excite(excitation_scenario(ARM, 10.0), out)
    return out, summary


@pytest.fixture(scope="module")
def hidden_record(tmp_path_factory):
    out = tmp_path_factory.mktemp("excite") / "hidden"
    excite(excitation_scenario(ARM, 20.0), out, physics=HIDDEN)
    return out


def test_excitation_stays_inside_limits_without_intervention(nominal_record):
    out, summary = nominal_record
    assert [e["kind"] for e in summary["events"]] == ["retreat_begin", "retreat_done"]
    profile = make_cell(ARM).profile
    with open_record(out) as rec:
        ticks = rec.ticks(rate="all")
        end_ns = next(rec.cycles()).t_end_ns
    assert np.all(np.diff(ticks.t_ns) == 1_000_000)  # every tick recorded
    moving = ticks.t_ns <= end_ns  # the excitation; the retreat after it is a transition
    cmd, dt = ticks.q_cmd[moving], 1e-3
    np.testing.assert_array_equal(ticks.q_ref[moving], cmd)  # the envelope changed nothing
    assert np.all(cmd >= profile.q_min) and np.all(cmd <= profile.q_max)
    vel = np.diff(cmd, axis=0) / dt
    acc = np.diff(vel, axis=0) / dt
    assert np.all(np.abs(vel).max(axis=0) <= profile.array("velocity"))
    assert np.all(np.abs(acc).max(axis=0) <= profile.array("acceleration"))
    span = ticks.q_meas[moving].max(axis=0) - ticks.q_meas[moving].min(axis=0)
    hinges = [i for i, j in enumerate(profile.joints) if j.kind == "hinge"]
    assert np.all(span[hinges] > 0.25), span  # each arm joint moves a useful stretch (0.6 rad at most)
    assert np.all(span[hinges] > 0.05 * (profile.q_max - profile.q_min)[hinges])


@settings(max_examples=25, deadline=None)
@given(st.floats(0.0, 1.0), st.integers(0, 1000))
def test_series_respects_every_limit_from_any_start(where, seed):
    profile = make_cell(ARM).profile
    q0 = profile.q_min + where * (profile.q_max - profile.q_min)
    policy = ExcitationPolicy.for_profile(profile, q0, seed=seed)
    t = np.arange(0.0, 12.0, 1e-3)
    q = policy.at(t)
    room = MARGIN * np.minimum(q0 - profile.q_min, profile.q_max - q0) + 1e-12
    assert np.all(np.abs(q - q0) <= room)
    for n, limit in enumerate(("velocity", "acceleration", "jerk"), start=1):
        q = np.diff(q, axis=0) / 1e-3
        assert np.all(np.abs(q[n:]) <= MARGIN * profile.array(limit) * 1.05), limit


def test_identify_recovers_hidden_physics(hidden_record):
    cell = make_cell(ARM)
    result = identify(load_segments([hidden_record], cell), cell, parse_params("friction,armature,delay,kp", cell))
    by = {(e["parameter"], e["joint"]): e for e in result["estimates"]}
    assert by[("delay", None)]["value"] == pytest.approx(HIDDEN.delay_s, abs=1e-3)
    for joint in cell.profile.joint_names[:5]:
        friction = by[("friction", joint)]
        truth = friction["nominal"] * HIDDEN.friction.get(joint, 1.0)
        assert friction["value"] == pytest.approx(truth, rel=0.10), joint
        if joint in HIDDEN.friction:  # the change is seen: the nominal value lies outside the interval
            assert not friction["interval"][0] <= friction["nominal"] <= friction["interval"][1]
        armature = by[("armature", joint)]
        assert armature["value"] == pytest.approx(armature["nominal"] * HIDDEN.armature, rel=0.10), joint
        assert by[("kp", joint)]["value"] == pytest.approx(by[("kp", joint)]["nominal"], rel=0.02)
    for e in result["estimates"]:  # each interval holds the method's measured bias beyond the noise
        low, high = e["interval"]
        assert np.isfinite(e["method_bias"]) and (high - low) / 2 > abs(e["method_bias"]), e


def test_replay_with_the_true_values_reproduces_the_record(hidden_record):
    """The bias check's replay is the cell's own physics: with the hidden truth put in, it retraces the
    recorded motion, and its effort differs from the recorded current only by the sensor's noise."""
    cell = make_cell(ARM)
    segments = load_segments([hidden_record], cell)
    m, drives = cell.model, cell.drives
    values = {}
    for i in [i for i, j in enumerate(cell.profile.joints) if j.kind == "hinge"]:
        name, dof = cell.profile.joint_names[i], drives.dadr[i]
        values |= {("armature", name): m.dof_armature[dof] * HIDDEN.armature, ("damping", name): m.dof_damping[dof],
                   ("friction", name): m.dof_frictionloss[dof] * HIDDEN.friction.get(name, 1.0),
                   ("kp", name): m.actuator_gainprm[drives.act[i], 0]}
    hinges = [i for i, j in enumerate(cell.profile.joints) if j.kind == "hinge"]
    noise = cell.drives.current_noise * cell.profile.array("torque_constant")[hinges]  # [N*m]
    for lag, close in ((4, True), (0, False)):  # the record's delay, and a wrong one
        for s, r in zip(segments, simulate(segments, cell, lag, values)):
            error = np.abs(r.q - s.q)[:, hinges].max(axis=0)  # [rad]
            if close:  # (not to the last bit: the record's friction solver starts warm, the replay's cold)
                assert np.all(error < 1e-5), error
                np.testing.assert_allclose(np.std((r.tau - s.tau)[1:, hinges], axis=0), noise, rtol=0.05)
            else:
                assert np.all(error > 1e-4), error


def test_an_unexcited_parameter_is_reported_not_identifiable(nominal_record):
    out, _ = nominal_record
    cell = make_cell(ARM)
    segments = load_segments([out], cell)
    held = []
    for s in segments:  # as if wrist_roll had been held still: no sample of it moves
        qd = s.qd.copy()
        qd[:, 4] = 0.0
        held.append(type(s)(s.q, qd, s.q_cmd, s.tau, s.record_id))
    result = identify(held, cell, ("friction",))
    by = {e["joint"]: e for e in result["estimates"]}
    assert by["wrist_roll"]["interval"] is None and by["wrist_roll"]["note"] == "not identifiable from this data"
    assert all(by[j]["interval"] is not None for j in cell.profile.joint_names[:4])
    still = [type(s)(s.q, s.qd * 0.0, s.q_cmd, s.tau, s.record_id) for s in segments]
    with pytest.raises(CalibrationError, match="move too little"):
        identify(still, cell, ("friction",))


def test_bad_input_is_one_line_and_exit_2(nominal_record, tmp_path):
    out, _ = nominal_record
    unknown = runner.invoke(app, ["identify", str(out), "--params", "friction,mass"])
    assert unknown.exit_code == 2 and "'mass'" in unknown.output and "allowed" in unknown.output
    other = runner.invoke(app, ["identify", str(out), "--cell", "quadruped-turns"])
    assert other.exit_code == 2 and "quadruped-turns" in other.output
    payload = runner.invoke(app, ["identify", str(out), "--cell", "quadruped-turns", "--params", "payload"])
    assert payload.exit_code == 2 and "'payload' is not a parameter of the quadruped-turns model" in payload.output
    # a record without motor current: a robot whose drives do not report it
    scenario = excitation_scenario(ARM, 1.0)
    run = Run(scenario, policy_factory=lambda: ExcitationPolicy.for_profile(make_cell(ARM).profile,
                                                                            make_cell(ARM).q_home))
    read = run.cell.drives.read

    def no_current(t_ns):
        state = read(t_ns)
        state.current[:] = np.nan
        return state

    run.cell.drives.read = no_current
    run_scenario(scenario, tmp_path / "nocurrent", run=run)
    missing = runner.invoke(app, ["identify", str(tmp_path / "nocurrent")])
    assert missing.exit_code == 2 and "no motor current" in missing.output
    assert len(missing.output.strip().splitlines()) == 1


def test_excite_cli_records(tmp_path):
    result = runner.invoke(app, ["excite", ARM, "--seconds", "7", "--out", str(tmp_path / "ex")])
    assert result.exit_code == 0, result.output
    assert "0 guard events" in result.output
    again = runner.invoke(app, ["excite", ARM, "--seconds", "7", "--out", str(tmp_path / "ex")])
    assert again.exit_code == 2  # a record already there is never overwritten


def test_write_profile_versions_and_keeps_the_old(hidden_record, tmp_path):
    from cellguard.embodiment import load_profile
    from cellguard.robot.arm_cell import ASSETS

    profile = tmp_path / "arm_profile.yaml"
    profile.write_bytes((ASSETS / "arm_profile.yaml").read_bytes())
    result = runner.invoke(app, ["identify", str(hidden_record), "--params", "friction,damping",
                                 "--write", str(profile)])
    assert result.exit_code == 0, result.output
    cell = make_cell(ARM)
    new = load_profile(cell.model, profile)
    assert "-cal-" in new.version
    friction = {m.joint: m for m in new.measured if m.parameter == "friction"}
    assert friction["elbow"].value == pytest.approx(0.3, rel=0.05) and friction["elbow"].method.startswith("sysid:")
    assert len(friction) == 5 and any(m.parameter == "backlash" for m in new.measured)  # others kept
    old = load_profile(cell.model, tmp_path / "arm_profile.2026-11-01.yaml")
    assert old.version == "2026-11-01" and old.sha256 == cell.profile.sha256
    quad = tmp_path / "quad.yaml"
    quad.write_bytes((ASSETS / "quadruped_profile.yaml").read_bytes())
    before = quad.read_bytes()
    wrong = runner.invoke(app, ["identify", str(hidden_record), "--write", str(quad)])
    assert wrong.exit_code == 2 and "robot" in wrong.output and quad.read_bytes() == before
