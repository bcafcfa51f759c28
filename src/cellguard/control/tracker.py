"""Tracker: the setpoint that follows the reference within the velocity, acceleration and jerk limits.

Transparency first. Each tick, per joint, the reference sample is checked as the next
setpoint: if the finite-difference velocity, acceleration and jerk of the setpoint sequence
with that sample appended are inside the limits, and the joint could still stop before its
soft position limit from there, the sample is sent exactly as it is (zero added delay, no
filter). Only the joints where it is not are handed to ruckig (community edition), so one
joint's intervention leaves the others untouched; the joints it recovers keep the direction
they close on the reference with (phase synchronisation, ``_SYNC``), each stops on its own:

* ``offset``: ruckig drives the *error* (setpoint minus reference) to zero within the headroom
  the reference leaves, so the setpoint lands exactly back on a moving reference and hands
  back to pass-through once it has (not on the first tick a sample fits). Chasing the
  reference's position instead would lag it by velocity times ruckig's horizon for as long as
  it moves.
* ``absolute``: ruckig's velocity interface toward the reference's velocity plus a position
  correction (the sample clipped to the soft limits), within the full limits; used when the offset candidate does not
  fit (the reference itself is too fast, or it heads past a limit).
* ``stop``: ruckig's velocity interface to zero velocity, each joint time-optimal.

A tool-speed cap (``ToolCap``, given on the ticks where it may bind) lowers each joint's velocity
limit: the cap is shared out along the velocity the absolute recovery aims for (the closing
velocity scaled as a whole, so the recovery keeps its direction) such that sum_j reach_j |v_j|
<= cap, which bounds the tool speed whatever each joint does within its share. The shares apply
once the sample breaks the cap and for as long as ruckig drives any joint; a sample under the cap
passes exactly.
Pass-through is refused where a sample is faster than its share, and ruckig brakes a joint that
is above its share within the acceleration and jerk limits (its start state is never clipped to
the lowered limit: that would be a velocity step).

Position limits are never clamped: a sample is refused when the stopping distance from its
velocity and acceleration no longer fits before the soft limit (a jerk-limited bound, more
than v²/2a), and the refusal hands over to ruckig while a stop still fits. A joint the setpoint
already has past a soft limit (a reset at the measured pose, a robot pushed by hand, past the hard
limit even) may come back inward, never go further out (``_stop_fits``). This edition of
ruckig ignores position limits and raises on NaN, so it only ever sees finite, clipped inputs,
and an error it raises brakes every joint for that tick (the envelope reports it as an event),
never an exception on the servo path.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np
import ruckig

from cellguard.control.reach import ToolCap

PASS, OFFSET, ABSOLUTE, STOP = 0, 1, 2, 3
GAIN = 8.0  # [1/s] position feedback of the absolute recovery; slow against the jerk ramps (A/J ~ 60 ms)
_PLANNED = (ruckig.Result.Working, ruckig.Result.Finished)  # what ruckig returns when it has a plan
# The joints of the absolute recovery keep the direction of their closing velocity: collinear profiles where
# ruckig can, else they arrive together. One by one, each at its own best, they ran on the sign pattern of their
# targets and the tool left the reference's path (out of the workspace box). Not under a tool-speed cap: from a
# state off that direction, the synchronised profiles left a joint above its share of the cap.
_SYNC = ruckig.Synchronization.Phase
# result codes of ruckig's result.hpp that this binding's enum does not name (it raises ValueError on them)
_UNNAMED = {"-101": "ErrorTrajectoryDuration: the trajectory duration exceeds its numerical limits",
            "-104": "ErrorZeroLimits: the trajectory conflicts with a limit of zero"}


class StopPlan(NamedTuple):
    """A stop of every joint planned whole (``Tracker.stop_plan``)."""

    duration: float  # [s]
    at: Callable[[float], list[float]]  # the positions (D plain floats) at a time into the stop [s]
    turning: tuple[int, ...]  # the joints whose stop may turn back; every other one moves one way only


class Tracker:
    """Setpoint state: position and its finite-difference velocity and acceleration, per joint.

    ``samples``: the same position, velocity and acceleration as plain floats (three lists of D),
    what the per-tick checks read.

    ``v_max``, ``a_max``, ``j_max``: shape (D,) [unit/s], [unit/s²], [unit/s³]; ``lo``, ``hi``:
    soft position limits (D,); ``dt``: servo period [s]. ``mode`` (D ints) says who drove each joint
    on the last tick (PASS, OFFSET, ABSOLUTE, STOP).
    """

    def __init__(self, q0: np.ndarray, v_max, a_max, j_max, lo, hi, dt: float):
        self.dt, self._inv_dt = dt, 1.0 / dt
        self.v_max, self.a_max, self.j_max = (np.array(x, dtype=np.float64) for x in (v_max, a_max, j_max))
        self.lo, self.hi = np.array(lo, dtype=np.float64), np.array(hi, dtype=np.float64)
        self._limits = np.stack([self.v_max, self.a_max, self.j_max]) * (1.0 + 1e-9) + 1e-12
        self._half_inv_j = 0.5 / self.j_max
        self._tail = self.a_max**3 / (6.0 * self.j_max**2)  # distance of the final jerk-up phase
        self._v3 = 0.5 * self.a_max**2 / self.j_max  # the velocity the final jerk-up phase removes
        self._v3sq, self._inv_2a = self._v3**2, 0.5 / self.a_max
        # a bound of the stopping distance at speed |v| for any |a| <= a_max: c0 + c1 |v| + v²/2a, padded by a
        # millionth for the acceleration the fit tolerates (a_max (1 + 1e-9) + 1e-12: the exact stop went 1e-11
        # past the bound, and a joint the bound cleared on one side went unchecked there)
        t1, pad = 2.0 * self.a_max / self.j_max, 1.0 + 1e-6
        self._far0 = (0.5 * self.a_max * t1 * t1 + self._tail) * pad + 1e-12
        self._far1, self._far2 = t1 * pad, self._inv_2a * pad
        # the same constants as plain floats: each tick runs joint by joint on Python floats, several times
        # cheaper than the dozens of numpy calls on (D,) arrays it would take for a handful of joints
        self._vmax_f, self._amax_f, self._jmax_f, self._lo_f, self._hi_f = (
            x.tolist() for x in (self.v_max, self.a_max, self.j_max, self.lo, self.hi))
        self._half_inv_j_f = self._half_inv_j.tolist()
        self._stop_consts = tuple(zip(*(x.tolist() for x in (self.a_max, self.j_max, self._v3, self._v3sq,
                                                              self._inv_2a, self._tail))))  # what _travel reads
        self._far_f = tuple(zip(*(x.tolist() for x in (self._far0, self._far1, self._far2, self.a_max))))
        self._jerk_tick = (self.j_max * dt).tolist()  # the acceleration one tick of full jerk removes
        self._vmax99_f = [0.99 * w for w in self._vmax_f]
        self._joints = tuple(zip(*(x.tolist() for x in (*self._limits, self._half_inv_j, self._far0, self._far1,
                                                          self._far2, self.lo, self.hi))))  # what _fits reads
        dof = len(self.v_max)
        self._absolute_in, self._offset_in, self._stop_in = (
            self._input(dof, ruckig.ControlInterface.Velocity), self._input(dof, ruckig.ControlInterface.Position),
            self._input(dof, ruckig.ControlInterface.Velocity))
        # one generator and output per input: ruckig continues the trajectory held in the output
        # when it judges the input unchanged, and a shared output was seen to return another plan's
        self._otg = {id(inp): (ruckig.Ruckig(dof, dt), ruckig.OutputParameter(dof))
                     for inp in (self._absolute_in, self._offset_in, self._stop_in)}
        self._stop_in.target_velocity = np.zeros(dof)
        self._planner, self._plan = ruckig.Ruckig(dof), ruckig.Trajectory(dof)  # a stop planned whole (stop_plan)
        self._offset_in.target_position = np.zeros(dof)  # the error's target: none
        # the least headroom the offset plan keeps for v, a, j
        self._floors = tuple((0.05 * x).tolist() for x in (self.v_max, self.a_max, self.j_max))
        self._stop_in.target_acceleration = self._absolute_in.target_acceleration = np.zeros(dof)
        self.failed: str | None = None  # why ruckig refused the recovery, which then braked every joint
        self._error: str | None = None  # why ruckig refused its last input
        self._finished = False  # ruckig's last plan ends within this tick (the state is its target)
        self.reset(q0)

    def _input(self, dof: int, interface) -> ruckig.InputParameter:
        inp = ruckig.InputParameter(dof)
        inp.control_interface = interface
        inp.synchronization = ruckig.Synchronization.No
        inp.max_velocity, inp.max_acceleration, inp.max_jerk = self.v_max, self.a_max, self.j_max
        return inp

    def reset(self, q: np.ndarray) -> None:
        """Standstill at ``q`` (D,)."""
        self.p = np.array(q, dtype=np.float64)
        dof = len(self.p)
        self.samples = (self.p.tolist(), [0.0] * dof, [0.0] * dof)
        self.mode = [PASS] * dof  # replaced, never changed in place: a reader may keep last tick's
        self._tv, self._ta = [0.0] * dof, [0.0] * dof  # ruckig's own velocity and acceleration of joints it drove
        self._ref = None  # last reference sample and its FD v, a; None: the setpoint's (it passed through)
        self._passing = True  # every joint passed through on the last tick

    # -- the checks ------------------------------------------------------------------------
    def _stop_distance(self, j: int, v: float, a: float) -> float:
        """Distance [unit] a jerk-limited stop of joint ``j`` from velocity ``v`` and acceleration ``a``
        covers in the + direction (``_travel``)."""
        return _travel(v, a, *self._stop_consts[j])

    def _stop_fits(self, j: int, q: float, v: float, a: float, upper: bool = True, lower: bool = True) -> bool:
        """Would a jerk-limited stop of joint ``j`` from (q, v, a) end inside its soft limits (the ``upper``
        and ``lower`` one: a limit the loose bound already clears needs no exact check)?

        Past one already (``p``, the setpoint now: a reset at the measured pose, a robot pushed by hand),
        ``q`` fits if it is no further out than ``p`` and a stop from it ends no further out than ``q``,
        so the joint may come back inward and never go out. Held to the limit alone, it was frozen there.
        """
        p = self.samples[0][j]
        return ((not upper or q + self._stop_distance(j, v, a) <= max(self._hi_f[j], min(q, p)))
                and (not lower or q - self._stop_distance(j, -v, -a) >= min(self._lo_f[j], max(q, p))))

    def _stop_clears(self, j: int, q: float, v: float, a: float) -> bool:
        """``_stop_fits`` for a state inside the acceleration limit that a loose bound of its stopping distance
        (the one ``_fits`` screens with) puts clear of both soft limits: no exact check there."""
        far0, far1, far2, a_max = self._far_f[j]
        speed = abs(v)
        far = far0 + speed * (far1 + speed * far2)
        if -a_max <= a <= a_max and self._lo_f[j] <= q - far and q + far <= self._hi_f[j]:
            return True
        return self._stop_fits(j, q, v, a)

    def _fits(self, q: list[float], v_limit: list[float] | None = None, only: list[int] | None = None
              ) -> tuple[list[bool], list[float], list[float]]:
        """Per joint (of ``only`` where given, in its order): can ``q[j]`` be the next setpoint? And the
        finite-difference v, a it implies.

        Yes when its finite-difference v, a, j are inside the limits (``v_limit``, D plain floats,
        in place of the velocity limits where given), its acceleration can be brought to zero before
        the velocity limit (a state ruckig could take over from without overshooting it), and a stop
        from it still fits before the soft position limits (checked exactly only for joints a loose
        bound puts near a limit).
        """
        inv_dt, half_dt = self._inv_dt, 0.5 * self.dt
        joints = self._joints if v_limit is None else [(w, *rest) for w, (_, *rest) in zip(v_limit, self._joints)]
        if only is None:
            rows = zip(range(len(q)), q, *self.samples, joints)
        else:  # the few joints a recovery plan moved
            p, sv, sa = self.samples
            rows = ((j, q[j], p[j], sv[j], sa[j], joints[j]) for j in only)
        ok, vs, accs = [], [], []
        for j, qj, pj, vj, aj, (v_max, a_max, j_max, half_inv_j, far0, far1, inv_2a, lo, hi) in rows:
            v = (qj - pj) * inv_dt
            a = (v - vj) * inv_dt
            # inside v, a, j; and the acceleration can still be brought to zero (jerk-limited) before v_max,
            # and a stop still fits, both from the velocity at the end of the tick (v is its mean over the
            # tick): what ruckig would start from (at a 5 ms period the mean read 10 mm/s slow on the gripper)
            v_end = v + a * half_dt
            fit = (-v_max <= v <= v_max and -a_max <= a <= a_max and -j_max <= (a - aj) * inv_dt <= j_max
                   and -v_max <= v_end + a * abs(a) * half_inv_j <= v_max)
            speed = v_end if v_end >= 0.0 else -v_end
            far = far0 + speed * (far1 + speed * inv_2a)  # a loose bound of the stopping distance
            if fit and (qj - far < lo or qj + far > hi):  # (a gripper's short range: on half the ticks, one side)
                fit = self._stop_fits(j, qj, v_end, a, qj + far > hi, qj - far < lo)
            ok.append(fit)
            vs.append(v)
            accs.append(a)
        return ok, vs, accs

    # -- one tick --------------------------------------------------------------------------
    def follow(self, r: np.ndarray, cap: ToolCap | None = None) -> np.ndarray:
        """The next setpoint (D,) for the finite reference sample ``r`` (D,); sets ``mode``.

        ``cap``: a tool-speed cap in joint terms at the setpoint, given where it may bind.
        Joint by joint on plain floats (ruckig takes and returns lists), as in ``_fits``.
        """
        samples = r.tolist()
        ok, v, a = self._fits(samples)
        if cap is None and self._passing and all(ok):
            # pass-through after pass-through: the setpoint state is the reference's, and _fits()
            # has just computed its finite differences
            self.samples, self.p, self._ref = (samples, v, a), r, None
            return r
        if self._ref is None:  # the setpoint passed through: the reference's derivatives are _fits()'s
            previous, rv, ra = self.samples, v, a
        else:
            previous, inv_dt = self._ref, self._inv_dt
            rv = [(x - x0) * inv_dt for x, x0 in zip(samples, previous[0])]
            ra = [(x - x0) * inv_dt for x, x0 in zip(rv, previous[1])]
        self._ref = (samples, rv, ra)
        v_limit = None
        if cap is not None:
            v_limit = self._share(samples, rv, cap)
            ok = self._fits(samples, v_limit)[0]
        recovering = self._landable(samples, rv, ra, previous, v_limit)
        if all(ok) and not recovering:
            return self._commit(r, samples, None, None, PASS)
        q, tv, ta = samples.copy(), self._tv.copy(), self._ta.copy()
        mode = [PASS if fit else ABSOLUTE for fit in ok]
        if recovering and self._offset(recovering, rv, ra, previous, v_limit):
            out = self._out
            cand = [x + e for x, e in zip(samples, out.new_position)]
            fits, ev, ea = self._fits(cand, v_limit, recovering)[0], out.new_velocity, out.new_acceleration
            half_dt = 0.5 * self.dt
            for j, fit in zip(recovering, fits):
                if self._finished and ok[j]:  # landed: the sample itself, passed through again
                    continue
                if fit:
                    q[j], mode[j], tv[j], ta[j] = cand[j], OFFSET, ev[j] + _at_end(rv[j], ra[j], half_dt), ea[j] + ra[j]
        rest = [j for j, m in enumerate(mode) if m == ABSOLUTE]
        if rest:
            if not self._absolute(samples, rv, v_limit):
                self.failed = self._error
                return self.stop()
            out = self._out
            nq, nv, na = out.new_position, out.new_velocity, out.new_acceleration
            brake = []
            for j in rest:
                q[j], tv[j], ta[j] = nq[j], nv[j], na[j]
                if not self._stop_clears(j, nq[j], nv[j], na[j]):  # heading past a soft limit: brake this joint
                    brake.append(j)
            if brake and self._brake():
                out = self._out
                bq, bv, ba = out.new_position, out.new_velocity, out.new_acceleration
                for j in brake:
                    q[j], mode[j], tv[j], ta[j] = bq[j], STOP, bv[j], ba[j]
        return self._commit(np.array(q), q, tv, ta, mode)

    def stop(self, r: np.ndarray | None = None) -> np.ndarray:
        """One tick of a time-optimal stop of every joint (velocity interface to zero).

        ``r``, this tick's reference sample, keeps the reference's derivatives current for when
        tracking resumes.
        """
        zero = [0.0] * len(self.p)
        if r is not None:
            self._ref = (r.tolist(), zero, zero)
        if not self._brake():  # cannot happen with finite inputs; hold rather than raise
            return self._commit(self.p.copy(), self.samples[0], zero, zero, STOP)
        out = self._out
        v, a = out.new_velocity, out.new_acceleration
        if all(abs(x) < 1e-9 for x in v) and all(abs(x) < 1e-6 for x in a):  # at rest: hold exactly, no drift
            return self._commit(self.p.copy(), self.samples[0], zero, zero, STOP)
        q = out.new_position
        return self._commit(np.array(q), q, v, a, STOP)

    def stop_travel_bound(self, joints: tuple[int, ...], weights: list[tuple[float, float, float]]
                          ) -> tuple[float, float, float]:
        """Sum over ``joints`` of their ``weights`` (x, y, z per joint: how far the tool point may move per unit of
        the joint's travel) times a looser bound of ``stop_travel`` that holds whatever the acceleration within
        the limit (the one ``_fits`` screens with): a few multiplications, where ``stop_travel`` costs a call."""
        half_dt, v_all, far = 0.5 * self.dt, self.samples[1], self._far_f
        rx = ry = rz = 0.0
        for j, (kx, ky, kz) in zip(joints, weights):
            c0, c1, c2, a_max = far[j]
            v = v_all[j]
            speed = (v if v >= 0.0 else -v) + a_max * half_dt
            d = c0 + speed * (c1 + speed * c2)
            rx, ry, rz = rx + kx * d, ry + ky * d, rz + kz * d
        return rx, ry, rz

    def stop_travel(self, joints: tuple[int, ...], weights: list[tuple[float, float, float]]
                    ) -> tuple[float, float, float]:
        """Sum over ``joints`` of their ``weights`` (as in ``stop_travel_bound``) times how far a stop from the
        setpoint state could take the joint either way (``_travel``), from the state at the end of the tick. A
        way its velocity and acceleration both lead away from is not computed: nothing there (the box asks on
        every tick)."""
        half_dt, (_, v_all, a_all), consts = 0.5 * self.dt, self.samples, self._stop_consts
        rx = ry = rz = 0.0
        for j, (kx, ky, kz) in zip(joints, weights):
            a = a_all[j]
            v = v_all[j] + a * half_dt
            d = _travel(v, a, *consts[j]) if v > 0.0 or a > 0.0 else 0.0
            if v < 0.0 or a < 0.0:
                d = max(d, _travel(-v, -a, *consts[j]))
            rx, ry, rz = rx + kx * d, ry + ky * d, rz + kz * d
        return rx, ry, rz

    def stop_plan(self) -> StopPlan | None:
        """The stop ``stop`` would run from the setpoint state, planned whole (``StopPlan``). None where ruckig
        refuses the state (then ``stop`` holds)."""
        inp, v_all, a_all = self._stop_input()
        try:
            if self._planner.calculate(inp, self._plan) not in _PLANNED:
                return None
        except (ruckig.RuckigError, ValueError):
            return None
        plan = self._plan
        # a joint turns back where its velocity, with the acceleration brought to zero at full jerk, changes
        # sign: a stop from there moves it both ways (``_travel`` is zero one way for every other joint)
        turning = tuple(j for j, (v, a, h) in enumerate(zip(v_all, a_all, self._half_inv_j_f))
                        if (v < 0.0 or (a < 0.0 and v < a * a * h)) and (v > 0.0 or (a > 0.0 and v > -a * a * h)))
        return StopPlan(plan.duration, lambda t: plan.at_time(t)[0], turning)

    def snapshot(self) -> tuple:
        """The setpoint state, to ``restore`` if the setpoint just computed may not be sent after all."""
        return self.p, self.samples, self.mode, self._tv, self._ta, self._ref, self._passing

    def restore(self, state: tuple) -> None:
        """Back to a ``snapshot`` (its lists are replaced on every tick, never changed in place)."""
        self.p, self.samples, self.mode, self._tv, self._ta, self._ref, self._passing = state

    def hold(self) -> np.ndarray:
        """Standstill where the setpoint is, at once: power is removed, nothing is driven."""
        self.reset(self.p)
        self.mode = [STOP] * len(self.mode)
        self._passing = False
        return self.p.copy()

    @property
    def passing(self) -> bool:
        """Every joint passed through on the last tick (``mode`` all PASS)."""
        return self._passing

    @property
    def stopped(self) -> bool:
        """Standstill: the last two setpoints are equal and the acceleration is zero."""
        return not (any(self.samples[1]) or any(self.samples[2]))

    # -- ruckig ------------------------------------------------------------------------------
    def _handover(self) -> tuple[list[float], list[float]]:
        """ruckig's start state for a plan on absolute positions: its own where such a plan drove the joint last
        tick, else what the samples imply (velocity at the end of the last tick). A replanning tracker must
        start from its own state: restarting from a lagging estimate each tick makes it overshoot. An offset
        plan's state rides on the reference's estimated derivatives, so a joint it drove starts from the
        samples here.
        """
        half_dt, v, a = 0.5 * self.dt, [], []
        for m, own_v, own_a, sv, sa in zip(self.mode, self._tv, self._ta, *self.samples[1:]):
            vj, aj = (own_v, own_a) if m >= ABSOLUTE else (sv + sa * half_dt, sa)
            v.append(vj)
            a.append(aj)
        return v, a

    def _brake(self) -> bool:
        return self._step(self._stop_input()[0])

    def _stop_input(self) -> tuple[ruckig.InputParameter, list[float], list[float]]:
        """ruckig's input for a stop of every joint from the hand-over state, and that state's v and a."""
        inp = self._stop_in
        v, a = self._handover()
        inp.current_position, inp.current_velocity, inp.current_acceleration = self.samples[0], v, a
        return inp, v, a

    def _closing(self, r: list[float], rv: list[float]) -> list[float]:
        """The velocity that closes on the reference sample ``r``: the sample's velocity plus ``GAIN``
        times the position error (the sample clipped to the soft limits)."""
        closing = []
        for x, x_v, pj, lo, hi in zip(r, rv, self.samples[0], self._lo_f, self._hi_f):
            t = min(max(x, lo), hi)
            closing.append((x_v if t == x else 0.0) + GAIN * (t - pj))
        return closing

    def _share(self, r: list[float], rv: list[float], cap: ToolCap) -> list[float]:
        """Per-joint velocity limits w with sum_j reach_j w_j <= the cap: the closing velocity scaled as a
        whole (so the recovery keeps its direction), never above a joint's own limit.

        A joint that cannot get down to its share this tick (its speed, or the peak its acceleration still
        carries it to, is above it) is charged that speed instead, and the others share what is left:
        one joint braking from above while another speeds up into its share ran the tool past the cap.
        """
        closing = [abs(c) for c in self._closing(r, rv)]
        v, a = self._handover()
        held = [max(abs(x), abs(x + y * abs(y) * h)) for x, y, h in zip(v, a, self._half_inv_j_f)]
        reach, budget, free = cap.reach, cap.limit, list(range(len(closing)))
        shares = [0.0] * len(closing)
        while free:  # each pass the scale can only fall: the joints charged more than their share leave
            need = sum(reach[j] * closing[j] for j in free)
            scale = budget / need if need > 0.0 else 0.0
            for j in free:
                shares[j] = min(closing[j] * scale, self._vmax_f[j])
            over = [j for j in free if held[j] > shares[j]]
            if not over:
                break
            budget = max(budget - sum(reach[j] * held[j] for j in over), 0.0)
            free = [j for j in free if j not in over]
        return shares

    def _absolute(self, r: list[float], rv: list[float], v_limit: list[float] | None = None) -> bool:
        """ruckig's velocity interface toward the velocity that closes on the reference sample
        (``_closing``), within the velocity limits (``v_limit`` where given).

        A position target with the sample's velocity as target state would be time-optimal for a
        *fixed* target, and may back away first to get a run-up; a moving target makes that run-up
        permanent. A joint whose acceleration (more than one tick of jerk removes) already carries it
        past the limit (taken over from a plan that rode the limit, or under a lowered one) is first
        asked for the velocity it peaks at when its acceleration is brought to zero at full jerk:
        time-optimal toward a target it must overshoot anyway, ruckig eases off the jerk and
        overshoots further. The closing velocity is scaled as a whole into the limits, not clipped
        joint by joint, so that it keeps its direction.
        """
        inp = self._absolute_in
        v, a = self._handover()
        inp.current_position, inp.current_velocity, inp.current_acceleration = self.samples[0], v, a
        inp.synchronization = _SYNC if v_limit is None else ruckig.Synchronization.No
        limit = self._vmax99_f if v_limit is None else [0.99 * w for w in v_limit]  # 1 % under the limits
        closing = self._closing(r, rv)
        scale = 1.0
        for c, w in zip(closing, limit):
            if c > w or c < -w:
                scale = min(scale, w / abs(c))
        target = []
        for c, w, vj, aj, half_inv_j, j_tick in zip(closing, limit, v, a, self._half_inv_j_f, self._jerk_tick):
            peak = vj + aj * abs(aj) * half_inv_j  # where the acceleration brought to zero at full jerk leaves it
            target.append(peak if (peak > w or peak < -w) and peak * aj > 0.0 and (aj > j_tick or aj < -j_tick)
                          else c * scale)
        inp.target_velocity = target
        return self._step(inp)

    def _landable(self, r: list[float], rv: list[float], ra: list[float], previous: tuple,
                  v_limit: list[float] | None) -> list[int]:
        """The joints ruckig was already recovering that an offset plan could land back on the reference,
        whether or not their sample fits (until the plan has landed, the setpoint crosses the reference at
        a speed of its own: the next sample would break the jerk limit and the recovery start over):
        those whose reference lies inside the soft limits and moves inside the velocity (``v_limit`` where
        given) and acceleration limits, now and last tick. Landing on a reference outside them cannot fit:
        the plan would run the joint at full speed toward a point it may not reach, into a state from
        which the absolute recovery overshoots the velocity limit; and an error state built on such
        derivatives (a jump read as 100 rad/s) makes ruckig refuse the whole plan, every joint's."""
        limit, a_max, lo, hi, (_, p_v, p_a) = (self._vmax_f if v_limit is None else v_limit, self._amax_f,
                                               self._lo_f, self._hi_f, previous)
        return [j for j, m in enumerate(self.mode)
                if (m == OFFSET or m == ABSOLUTE) and lo[j] <= r[j] <= hi[j] and -limit[j] <= rv[j] <= limit[j]
                and -limit[j] <= p_v[j] <= limit[j] and -a_max[j] <= ra[j] <= a_max[j]
                and -a_max[j] <= p_a[j] <= a_max[j]]

    def _offset(self, joints: list[int], rv: list[float], ra: list[float], previous: tuple,
                v_limit: list[float] | None = None) -> bool:
        """ruckig on the error e = setpoint - reference of ``joints``, from its state now to zero, within the
        headroom the reference leaves them (the other joints' error is planned from zero at the full limits:
        nothing to do). ruckig drove ``joints`` last tick (``_landable``): their state is its own."""
        inp = self._offset_in
        r0, rv0, ra0 = previous
        half_dt, inv_dt, p, tv, ta = 0.5 * self.dt, self._inv_dt, self.samples[0], self._tv, self._ta
        dof = len(p)
        e, ev, ea = [0.0] * dof, [0.0] * dof, [0.0] * dof
        limit = self._vmax_f if v_limit is None else v_limit
        v_max, a_max, j_max = list(limit), list(self._amax_f), list(self._jmax_f)
        v_floor, a_floor, j_floor = self._floors
        for j in joints:
            e[j], ev[j], ea[j] = p[j] - r0[j], tv[j] - _at_end(rv0[j], ra0[j], half_dt), ta[j] - ra0[j]
            v_max[j] = max(v_max[j] - abs(rv[j]), v_floor[j])
            a_max[j] = max(a_max[j] - abs(ra[j]), a_floor[j])
            j_max[j] = max(j_max[j] - abs(ra[j] - ra0[j]) * inv_dt, j_floor[j])
        inp.current_position, inp.current_velocity, inp.current_acceleration = e, ev, ea
        inp.synchronization = _SYNC if v_limit is None else ruckig.Synchronization.No
        inp.max_velocity, inp.max_acceleration, inp.max_jerk = v_max, a_max, j_max
        return self._step(inp)

    def _step(self, inp) -> bool:
        otg, self._out = self._otg[id(inp)]
        try:
            result = otg.update(inp, self._out)
        except (ruckig.RuckigError, ValueError) as exc:  # ValueError: a result code the binding does not name
            self._error = failure_text(exc)
            otg.reset()
            return False
        self._error = None if result in _PLANNED else str(result)
        self._finished = result == ruckig.Result.Finished
        return self._error is None

    def _commit(self, q: np.ndarray, samples: list[float], tv: list[float] | None, ta: list[float] | None,
                mode: int | list[int]) -> np.ndarray:
        """Make ``q`` (D,), equal to ``samples`` (D plain floats), the setpoint; ``mode``: one for all or per joint."""
        inv_dt, (p, v0, _) = self._inv_dt, self.samples
        v = [(x - x0) * inv_dt for x, x0 in zip(samples, p)]
        self.p, self.samples = q, (samples, v, [(x - x0) * inv_dt for x, x0 in zip(v, v0)])
        one = isinstance(mode, int)
        self.mode = [mode] * len(samples) if one else mode
        self._passing = one and mode == PASS
        if tv is not None:
            self._tv, self._ta = tv, ta
        return q


def _at_end(v: float, a: float, half_dt: float) -> float:
    """The velocity at the end of a tick from its finite-difference velocity ``v`` (the mean over the
    tick) and acceleration ``a``, as ``_handover`` reads the samples: the offset plan's error is the
    setpoint's state less the reference's at the same instant. Taken at mid-tick, the reference's
    velocity was half a tick of its acceleration short, a step at every hand-over between the plans."""
    return v + a * half_dt


def _travel(v: float, a: float, amax: float, jmax: float, v3: float, v3sq: float, inv_2a: float,
            tail: float) -> float:
    """Distance [unit] a jerk-limited stop from velocity ``v`` and acceleration ``a`` covers in the +
    direction: jerk down to -amax, hold it, jerk back to zero as velocity reaches zero (``v3``: the
    velocity that last phase removes, ``tail``: its distance). Exact for that profile; where the
    velocity runs out before -amax is reached it falls back to a looser bound, so it is never shorter
    than ruckig's time-optimal stop. Zero where the velocity stays <= 0 with the acceleration brought to
    zero at full jerk: a joint braking a motion in - never turns back (a joint heading back inward from
    past a limit brakes that way; the looser bound would refuse every such tick). Plain floats: for a
    handful of joints this is several times cheaper than array arithmetic on the servo tick.
    """
    t1 = (max(a, -amax) + amax) / jmax
    v1 = v + t1 * (a - 0.5 * jmax * t1)
    if v1 >= v3:
        return t1 * (v + t1 * (0.5 * a - jmax * t1 / 6.0)) + (v1 * v1 - v3sq) * inv_2a + tail
    if v > 0.0 or (a > 0.0 and v + 0.5 * a * a / jmax > 0.0):  # else the stop never turns to +
        return max(v, 0.0) * t1 + 0.5 * max(a, 0.0) * t1 * t1 + tail
    return 0.0


def failure_text(exc: Exception) -> str:
    """ruckig's error as one line; a result code the binding does not name gets its name from result.hpp."""
    text = str(exc).strip().splitlines()[0]
    name = _UNNAMED.get(text.split(" ", 1)[0])
    return f"{name} (result {text.split(' ', 1)[0]})" if name else text
