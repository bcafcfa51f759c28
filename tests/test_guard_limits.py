"""Each joint limit on its own: a reference that breaks exactly one of them, and what the envelope sends.

Deterministic and fast (a second of ticks, no physics), so that the mutation check (``tests/mutations``)
can run them for every mutation; the hypothesis properties cover arbitrary chunk streams.
Families per joint: a sinusoid about mid-range whose velocity, acceleration or jerk is 1.3 times
the limit while the other two stay below 0.9 of theirs (amplitude kept inside the range), and one
that swings 10 % past the hard limits slowly. Tolerances as in ``test_envelope_properties``; the
soft limits are held to 10 % of the margin (the stopping-distance bound is not exact: measured
overshoot at most 6 % of the margin, on the gripper), the hard limits exactly.
"""

from __future__ import annotations

import numpy as np
import pytest
from arm_limits import A, A_TOL, DT, HI, J, J_TOL, LO, MARGIN, MID, PROFILE, V, V_TOL

from cellguard.control.config import GuardConfig
from cellguard.control.envelope import Envelope
from cellguard.control.tracker import failure_text
from cellguard.robot.protocol import SafetyInputs
from cellguard.robot.registry import make_cell

P_TOL = 1e-9


def _sinusoid(which: str) -> tuple[np.ndarray, np.ndarray]:
    """Amplitude and angular frequency (D,) whose derivative ``which`` peaks at 1.3 x its limit."""
    over, under = 1.3, 0.9
    if which == "velocity":
        w = under * A / (over * V)  # acceleration at 0.9 of its limit
    elif which == "acceleration":
        w = np.sqrt(over * A / (under * V) * under * J / (over * A))  # between the two bounds
    else:
        w = over * J / (under * A)  # acceleration at 0.9 of its limit
    k = {"velocity": 1, "acceleration": 2, "jerk": 3}[which]
    amp = over * {"velocity": V, "acceleration": A, "jerk": J}[which] / w**k
    return np.minimum(amp, 0.4 * (HI - LO)), w


def _follow(reference, ticks: int, stop_at: int | None = None, category: int = 2):
    r0 = reference(0.0)
    envelope = Envelope(PROFILE, r0, 1_000_000)
    out, powered, kinds = np.empty((ticks, PROFILE.dof)), np.ones(ticks, dtype=bool), []
    for k in range(ticks):
        safety = SafetyInputs(stop=category) if stop_at is not None and k >= stop_at else SafetyInputs()
        out[k], events = envelope.apply((k + 1) * 1_000_000, reference((k + 1) * DT), None, safety)
        powered[k] = envelope.power
        kinds += [e.kind for e in events]
    return np.vstack([r0, out]), np.concatenate([[True], powered]), kinds


def _derivatives(q):
    v = np.diff(q, axis=0) / DT
    a = np.diff(v, axis=0) / DT
    return v, a, np.diff(a, axis=0) / DT


def _assert_inside(q, jerk: bool = True):
    assert (q >= LO - P_TOL).all() and (q <= HI + P_TOL).all(), "hard position limit"
    assert (q >= LO + 0.9 * MARGIN).all() and (q <= HI - 0.9 * MARGIN).all(), "soft position limit"
    v, a, j = _derivatives(q)
    assert (np.abs(v) <= V * (1 + V_TOL)).all(), np.abs(v).max(axis=0) / V
    assert (np.abs(a) <= A * (1 + A_TOL)).all(), np.abs(a).max(axis=0) / A
    if jerk:
        assert (np.abs(j) <= J * (1 + J_TOL)).all(), np.abs(j).max(axis=0) / J


@pytest.mark.parametrize("which", ["velocity", "acceleration", "jerk"])
def test_a_reference_over_one_derivative_limit_is_brought_inside(which):
    amp, w = _sinusoid(which)
    reference = lambda t: MID + amp * np.sin(w * t)  # noqa: E731
    ref = reference(np.arange(1201)[:, None] * DT)
    peaks = {"velocity": (amp * w / V).max(), "acceleration": (amp * w**2 / A).max(), "jerk": (amp * w**3 / J).max()}
    assert peaks[which] > 1.25  # the reference really breaks this limit
    q, _, kinds = _follow(reference, 1200)
    _assert_inside(q, jerk=which != "velocity")
    assert "limit_intervention" in kinds
    assert (np.ptp(q, axis=0) >= 0.3 * np.ptp(ref, axis=0)).all()  # still follows, not frozen


def test_jerk_stays_inside_while_a_joint_is_held_at_its_velocity_limit():
    """It reached 2.2 times the limit: the absolute recovery clipped its start velocity to the limit (a
    velocity step) when its own plan rode just above it."""
    amp, w = _sinusoid("velocity")
    q, _, _ = _follow(lambda t: MID + amp * np.sin(w * t), 1200)
    j = _derivatives(q)[2]
    assert (np.abs(j) <= J * (1 + J_TOL)).all(), np.abs(j).max(axis=0) / J


def test_a_reference_past_the_hard_limits_stops_inside_the_soft_ones():
    amp = 0.3 * (HI - LO)  # from rest at mid-range to 10 % past the upper hard limit and back
    w = np.min([0.5 * V / amp, np.sqrt(0.5 * A / amp), np.cbrt(0.5 * J / amp)], axis=0)
    q, _, kinds = _follow(lambda t: MID + amp * (1.0 - np.cos(w * t)), 1500)
    _assert_inside(q)
    assert ((q >= HI - MARGIN - 1e-3) | (q <= LO + MARGIN + 1e-3)).any()  # it went right up to a soft limit


@pytest.mark.parametrize("category", [1, 2])
def test_a_stop_from_speed_reaches_zero_velocity_within_its_bound(category):
    amp, w = _sinusoid("velocity")
    amp, w = amp * 0.6, w  # 0.8 of the velocity limit
    q, powered, kinds = _follow(lambda t: MID + amp * np.sin(w * t), 1200, stop_at=400, category=category)
    _assert_inside(q[powered])
    v, a, _ = _derivatives(q)
    v0, a0 = v[399], a[398]
    peak = np.abs(v0) + a0 * a0 / (2 * J)
    bound = float(((np.abs(a0) + 2 * A) / J + peak / A).max()) + 3e-3  # a jerk-limited stop from (v0, a0)
    moving = np.flatnonzero(np.abs(v[400:]).max(axis=1) > 0)
    took = (moving[-1] + 1 if len(moving) else 0) * DT
    assert 0.05 < took <= bound, (took, bound)
    assert ("power_removed" in kinds) == (category == 1) and powered[-1] == (category == 2)


def test_a_ruckig_result_the_binding_does_not_name_is_named_in_the_event():
    # the binding raises "ValueError: -101 is not a valid Result." for codes its enum lacks (seen on the servo path)
    assert failure_text(ValueError("-101 is not a valid Result.")) == (
        "ErrorTrajectoryDuration: the trajectory duration exceeds its numerical limits (result -101)")
    assert failure_text(ValueError("[ruckig] error in step 1, dof: 0 input:\n  details")) == (
        "[ruckig] error in step 1, dof: 0 input:")


@pytest.mark.parametrize("blend_s", [0.001, 0.05, 0.2])
def test_a_reference_that_jumps_back_and_forth_never_makes_ruckig_refuse_a_plan(blend_s):
    """The offset plan was built for every joint from the reference's finite differences: a jump read as
    100 rad/s made ruckig refuse it ("error in step 1") on up to 1497 of 1500 ticks, each reported as braking."""
    from cellguard.control.guard import Guard
    from cellguard.policy.chunk import ActionChunk

    guard = Guard(PROFILE, MID, 1_000_000, GuardConfig(watchdog_s=10.0, blend_s=blend_s))
    setpoints, kinds = [MID], []
    for k in range(1500):
        t = (k + 1) * 1_000_000
        if k % 30 == 0:
            side = 0.3 if (k // 30) % 2 else -0.3
            guard.push(ActionChunk(np.tile(MID + side * (HI - LO), (10, 1)), t, 20_000_000), t)
        setpoint, events = guard.tick(t)
        setpoints.append(setpoint)
        kinds += [e.kind for e in events]
    assert "tracker_failed" not in kinds and "limit_intervention" in kinds
    _assert_inside(np.array(setpoints))


def test_a_joint_stops_inside_its_soft_limits_at_a_5_ms_servo_period():
    """The stop check read the mean velocity of the last tick as the velocity ruckig starts from: at 5 ms
    the gripper, sent to its hard limit in five steps, braked 10 mm/s late and reached the hard limit."""
    from cellguard.control.guard import Guard
    from cellguard.policy.chunk import ActionChunk

    q0 = make_cell("arm-pick-place").read().q
    target = q0.copy()
    target[5] = LO[5]
    guard = Guard(PROFILE, q0, 5_000_000, GuardConfig(watchdog_s=10.0, blend_s=0.001))
    setpoints = [q0]
    for k in range(400):
        t = (k + 1) * 5_000_000
        if k == 2:
            guard.push(ActionChunk(np.linspace(q0, target, 6)[1:], t, 20_000_000), t)
        setpoints.append(guard.tick(t)[0])
    q = np.array(setpoints)
    assert (q >= LO + 0.9 * MARGIN).all() and (q <= HI - 0.9 * MARGIN).all(), (q.min(axis=0) - LO) / MARGIN
    assert q[-1, 5] < LO[5] + 1.5 * MARGIN[5]  # it went up to the soft limit


def test_a_reference_that_speeds_up_past_the_velocity_limit_is_held_at_it():
    """From rest, inside the acceleration and jerk limits, to 1.3 times the velocity limit (the arm joints):
    pass-through until the velocity limit, then ruckig holds the joints at it."""
    speed = np.where(np.arange(PROFILE.dof) < 5, 1.3 * V, 0.0)
    ramp = float((1.875 * speed / (0.9 * A)).max())  # [s] a quintic speed-up, at most 0.9 of the acceleration limit

    def reference(t):
        x = np.clip(np.asarray(t, dtype=np.float64) / ramp, 0.0, 1.0)[..., None]
        travel = ramp * x**4 * (2.5 - x * (3.0 - x))  # the integral of the quintic smoothstep, times the ramp
        return MID + speed * (travel + np.maximum(np.asarray(t)[..., None] - ramp, 0.0)) - 0.4 * speed * ramp

    q, _, kinds = _follow(reference, 900)
    _assert_inside(q)
    assert "limit_intervention" in kinds
    assert (np.abs(_derivatives(q)[0]).max(axis=0)[:5] > 0.98 * V[:5]).all()  # up to the limit, not short of it
