"""A joint the setpoint starts past its soft limit comes back inward within the limits, never further out.

An operator reset puts the setpoint at the measured pose, which a robot pushed by hand (or a home pose past the
limit) may have past a soft limit, or past the hard one. Before, the stop check failed there on every tick: the
joint was braked from standstill for good (a ``limit_brake`` at the first tick) while the others moved on, and
not even a reference back inside moved it. Tolerances as in ``test_guard_limits``.
"""

from __future__ import annotations

import numpy as np
import pytest
import ruckig
from arm_limits import A, A_TOL, DT, HI, J, J_TOL, LO, MARGIN, MID, PROFILE, V, V_TOL

from cellguard.control.envelope import Envelope
from cellguard.control.tracker import STOP, Tracker

# (joint, side, how far out): the elbow and the gripper, above and below, half-way into the margin or 10 % of
# the range past the hard limit
STARTS = [(j, side, out) for j in (2, 5) for side in (1, -1)
          for out in (0.5 * MARGIN[j], MARGIN[j] + 0.1 * (HI - LO)[j])]


def _start(j: int, side: int, out: float) -> float:
    return (HI[j] - MARGIN[j] + out) if side > 0 else (LO[j] + MARGIN[j] - out)


def _run(j: int, start: float, reference, ticks: int = 1500, dt: float = DT):
    """Operator reset with joint ``j`` at ``start`` (the others mid-range), then ``reference(k)`` for joint ``j``:
    the setpoints (ticks + 1, D), the event kinds and how many ticks the tracker braked joint ``j``."""
    dt_ns = round(dt * 1e9)
    q0 = MID.copy()
    q0[j] = start
    envelope = Envelope(PROFILE, MID, dt_ns)
    envelope.reset(q0)
    out, kinds, braked = [q0], set(), 0
    for k in range(ticks):
        r = q0.copy()
        r[j] = reference(k)
        setpoint, events = envelope.apply((k + 1) * dt_ns, r)
        out.append(setpoint.copy())
        kinds |= {e.kind.value for e in events}
        braked += envelope.tracker.mode[j] == STOP
    return np.array(out), kinds, braked


def _assert_within_limits(q, dt: float = DT):
    v = np.diff(q, axis=0) / dt
    a = np.diff(v, axis=0) / dt
    for x, limit, tol in ((v, V, V_TOL), (a, A, A_TOL), (np.diff(a, axis=0) / dt, J, J_TOL)):
        assert (np.abs(x) <= limit * (1 + tol)).all(), np.abs(x).max(axis=0) / limit


def _assert_never_further_out(x, j: int, side: int):
    """While past the soft limit, no setpoint of joint ``j`` (its sequence ``x``) is further out than the one before."""
    soft = HI[j] - MARGIN[j] if side > 0 else LO[j] + MARGIN[j]
    outside = (x[:-1] - soft) * side > 0
    assert outside[0]
    assert ((np.diff(x) * side)[outside] <= 0.0).all(), (np.diff(x) * side)[outside].max()


@pytest.mark.parametrize("dt", [1e-3, 5e-3])
@pytest.mark.parametrize("how", ["step", "ramp", "smooth"])
@pytest.mark.parametrize(("j", "side", "out"), STARTS)
def test_a_joint_reset_past_its_soft_limit_follows_a_reference_back_inside(j, side, out, how, dt):
    """Back to mid-range at once, at constant speed, or smoothly, over a second. Each brakes its inward motion
    somewhere past the limit (the recovery slows as it nears the soft limit, the smooth reference slows): the
    stopping-distance bound must be zero there, not one jerk phase, or the tracker brakes the joint every few ticks."""
    start = _start(j, side, out)
    ticks = round(1.5 / dt)
    share = {"step": lambda s: 1.0, "ramp": lambda s: min(1.0, s),
             "smooth": lambda s: 0.5 - 0.5 * np.cos(np.pi * min(1.0, s))}[how]
    to_mid = lambda k: start + (MID[j] - start) * share(k * dt)  # noqa: E731
    q, kinds, braked = _run(j, start, to_mid, ticks, dt)
    x = q[:, j]
    assert x[-1] == MID[j]  # back on the reference, passed through
    assert braked == 0 and "limit_brake" not in kinds, kinds
    _assert_never_further_out(x, j, side)
    _assert_within_limits(q, dt)
    assert (q[:, np.arange(PROFILE.dof) != j] == np.delete(MID, j)).all()  # the others untouched


@pytest.mark.parametrize("how", ["outward", "back_and_forth"])
@pytest.mark.parametrize(("j", "side", "out"), STARTS)
def test_a_joint_past_its_soft_limit_never_moves_further_out(j, side, out, how):
    """A reference that heads further out (at once, or back and forth about the start): the joint goes to the soft
    limit, where the reference clipped to it is, and never further out on the way."""
    start = _start(j, side, out)
    swing = side * 0.1 * (HI - LO)[j]
    if how == "outward":
        reference = lambda k: start + swing * min(1.0, k / 500)  # noqa: E731
    else:
        reference = lambda k: start + swing * np.sin(k / 150)  # noqa: E731
    q, _, _ = _run(j, start, reference)
    x, soft = q[:, j], (HI[j] - MARGIN[j] if side > 0 else LO[j] + MARGIN[j])
    _assert_never_further_out(x, j, side)
    _assert_within_limits(q)
    assert (x * side).max() <= side * start  # never past where it started
    near = 1e-3 * MARGIN[j]  # the recovery closes on the soft limit exponentially (``GAIN``)
    assert ((x - soft) * side).min() <= near  # came in to the soft limit
    if how == "outward":
        assert abs(x[-1] - soft) <= near


@pytest.mark.parametrize(("j", "side", "out"), STARTS)
def test_a_joint_held_past_its_soft_limit_by_its_reference_stays_exactly_where_it_is(j, side, out):
    start = _start(j, side, out)
    q, kinds, braked = _run(j, start, lambda k: start, ticks=300)
    assert (q[:, j] == start).all() and braked == 0 and not kinds


def test_the_stopping_distance_bound_is_never_shorter_than_ruckigs_stop():
    """``_travel`` in the + direction against ruckig's time-optimal stop from random states, many of them braking a
    motion in - (where the bound is zero: the stop never turns back to +, which the inward recovery relies on)."""
    v_max, a_max, j_max = 3.0, 15.0, 1000.0
    tracker = Tracker([0.0], [v_max], [a_max], [j_max], [-3.0], [3.0], DT)
    otg, trajectory = ruckig.Ruckig(1), ruckig.Trajectory(1)
    inp = ruckig.InputParameter(1)
    inp.control_interface = ruckig.ControlInterface.Velocity
    inp.target_velocity, inp.target_acceleration = [0.0], [0.0]
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = [v_max], [a_max], [j_max]
    rng = np.random.default_rng(7)
    zero = 0
    for _ in range(3000):
        a = rng.uniform(-a_max, a_max)
        v = rng.uniform(-v_max, v_max) if rng.random() < 0.5 else -0.5 * a * abs(a) / j_max + rng.normal(0, 0.05)
        inp.current_position, inp.current_velocity, inp.current_acceleration = [0.0], [v], [a]
        assert otg.calculate(inp, trajectory) == ruckig.Result.Working
        reached = max(trajectory.at_time(t)[0][0] for t in np.linspace(0.0, trajectory.duration, 400))
        bound = tracker._stop_distance(0, v, a)
        assert reached <= bound + 1e-12, (v, a, reached, bound)
        zero += bound == 0.0 and a > 0.0
    assert zero > 300  # the braking states were exercised
