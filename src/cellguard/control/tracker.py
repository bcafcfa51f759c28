"""Tracker: the setpoint that follows the reference within the velocity, acceleration and jerk limits.

Transparency first. Each tick, per joint, the reference sample is checked as the next
setpoint: if the finite-difference velocity, acceleration and jerk of the setpoint sequence
with that sample appended are inside the limits, and the joint could still stop before its
soft position limit from there, the sample is sent exactly as it is (zero added delay, no
filter). Only the joints where it is not are handed to ruckig (community edition), each joint
on its own (no synchronisation, so one joint's intervention leaves the others untouched):

* ``offset``: ruckig drives the *error* (setpoint minus reference) to zero within the headroom
  the reference leaves, so the setpoint lands exactly back on a moving reference and hands
  back to pass-through. Chasing the reference's position instead would lag it by velocity
  times ruckig's horizon for as long as it moves.
* ``absolute``: ruckig's velocity interface toward the reference's velocity plus a position
  correction (the sample clipped to the soft limits), within the full limits; used when the offset candidate does not
  fit (the reference itself is too fast, or it heads past a limit).
* ``stop``: ruckig's velocity interface to zero velocity, each joint time-optimal.

Position limits are never clamped: a sample is refused when the stopping distance from its
velocity and acceleration no longer fits before the soft limit (a jerk-limited bound, more
than v²/2a), and the refusal hands over to ruckig while a stop still fits. This edition of
ruckig ignores position limits and raises on NaN, so it only ever sees finite, clipped inputs,
and an error it raises brakes every joint for that tick (the envelope reports it as an event),
never an exception on the servo path.
"""

from __future__ import annotations

import numpy as np
import ruckig

PASS, OFFSET, ABSOLUTE, STOP = 0, 1, 2, 3
GAIN = 8.0  # [1/s] position feedback of the absolute recovery; slow against the jerk ramps (A/J ~ 60 ms)
_PLANNED = (ruckig.Result.Working, ruckig.Result.Finished)  # what ruckig returns when it has a plan
# result codes of ruckig's result.hpp that this binding's enum does not name (it raises ValueError on them)
_UNNAMED = {"-101": "ErrorTrajectoryDuration: the trajectory duration exceeds its numerical limits",
            "-104": "ErrorZeroLimits: the trajectory conflicts with a limit of zero"}


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
        # a bound of the stopping distance at speed |v| for any |a| <= a_max: c0 + c1 |v| + v²/2a
        t1 = 2.0 * self.a_max / self.j_max
        self._far0, self._far1 = 0.5 * self.a_max * t1 * t1 + self._tail, t1
        # the same constants as plain floats: each tick runs joint by joint on Python floats, several times
        # cheaper than the dozens of numpy calls on (D,) arrays it would take for a handful of joints
        self._vmax_f, self._amax_f, self._jmax_f, self._lo_f, self._hi_f = (
            x.tolist() for x in (self.v_max, self.a_max, self.j_max, self.lo, self.hi))
        self._v3_f, self._v3sq_f, self._inv_2a_f, self._tail_f = (
            x.tolist() for x in (self._v3, self._v3sq, self._inv_2a, self._tail))
        self._joints = tuple(zip(*(x.tolist() for x in (*self._limits, self._half_inv_j, self._far0, self._far1,
                                                          self._inv_2a, self.lo, self.hi))))  # what _fits reads
        dof = len(self.v_max)
        self._absolute_in, self._offset_in, self._stop_in = (
            self._input(dof, ruckig.ControlInterface.Velocity), self._input(dof, ruckig.ControlInterface.Position),
            self._input(dof, ruckig.ControlInterface.Velocity))
        # one generator and output per input: ruckig continues the trajectory held in the output
        # when it judges the input unchanged, and a shared output was seen to return another plan's
        self._otg = {id(inp): (ruckig.Ruckig(dof, dt), ruckig.OutputParameter(dof))
                     for inp in (self._absolute_in, self._offset_in, self._stop_in)}
        self._stop_in.target_velocity = np.zeros(dof)
        self._offset_in.target_position = np.zeros(dof)  # the error's target: none
        # the least headroom the offset plan keeps for v, a, j
        self._floors = tuple((0.05 * x).tolist() for x in (self.v_max, self.a_max, self.j_max))
        self._stop_in.target_acceleration = self._absolute_in.target_acceleration = np.zeros(dof)
        self.failed: str | None = None
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
        """Distance [unit] a jerk-limited stop of joint ``j`` from velocity ``v`` and acceleration
        ``a`` covers in the + direction: jerk down to -a_max, hold it, jerk back to zero as
        velocity reaches zero. Exact for that profile; where the velocity runs out before -a_max
        is reached it falls back to a looser bound, so it is never shorter than ruckig's
        time-optimal stop. Plain floats: for a handful of joints near a limit this is several
        times cheaper than array arithmetic on the servo tick.
        """
        amax, jmax = self._amax_f[j], self._jmax_f[j]
        t1 = (max(a, -amax) + amax) / jmax
        v1 = v + t1 * (a - 0.5 * jmax * t1)
        if v1 >= self._v3_f[j]:
            return (t1 * (v + t1 * (0.5 * a - jmax * t1 / 6.0)) + (v1 * v1 - self._v3sq_f[j]) * self._inv_2a_f[j]
                    + self._tail_f[j])
        if v > 0.0 or a > 0.0:
            return max(v, 0.0) * t1 + 0.5 * max(a, 0.0) * t1 * t1 + self._tail_f[j]
        return 0.0

    def _stop_fits(self, j: int, q: float, v: float, a: float) -> bool:
        """Would a jerk-limited stop of joint ``j`` from (q, v, a) end inside its soft limits?"""
        return (q + self._stop_distance(j, v, a) <= self._hi_f[j]
                and q - self._stop_distance(j, -v, -a) >= self._lo_f[j])

    def _fits(self, q: list[float]) -> tuple[list[bool], list[float], list[float]]:
        """Per joint: can ``q[j]`` be the next setpoint? And the finite-difference v, a it implies.

        Yes when its finite-difference v, a, j are inside the limits, its acceleration can be
        brought to zero before the velocity limit, and a stop from it still fits before the soft
        position limits (checked exactly only for joints a loose bound puts near a limit).
        """
        inv_dt = self._inv_dt
        ok, vs, accs = [], [], []
        for j, (qj, pj, vj, aj, (v_max, a_max, j_max, half_inv_j, far0, far1, inv_2a, lo, hi)) in enumerate(
                zip(q, *self.samples, self._joints)):
            v = (qj - pj) * inv_dt
            a = (v - vj) * inv_dt
            speed = abs(v)
            # inside v, a, j; and the acceleration can still be brought to zero (jerk-limited) before v_max
            fit = (speed <= v_max and abs(a) <= a_max and abs((a - aj) * inv_dt) <= j_max
                   and abs(v + a * abs(a) * half_inv_j) <= v_max)
            far = far0 + speed * (far1 + speed * inv_2a)  # a loose bound of the stopping distance
            if fit and (qj - far < lo or qj + far > hi):
                fit = self._stop_fits(j, qj, v, a)
            ok.append(fit)
            vs.append(v)
            accs.append(a)
        return ok, vs, accs

    # -- one tick --------------------------------------------------------------------------
    def follow(self, r: np.ndarray) -> np.ndarray:
        """The next setpoint (D,) for the finite reference sample ``r`` (D,); sets ``mode``.

        Joint by joint on plain floats (ruckig takes and returns lists), as in ``_fits``.
        """
        samples = r.tolist()
        ok, v, a = self._fits(samples)
        if self._passing and all(ok):
            # pass-through after pass-through: the setpoint state is the reference's, and _fits()
            # has just computed its finite differences
            self.samples, self.p, self._ref = (samples, v, a), r, None
            return r
        previous = self.samples if self._ref is None else self._ref
        inv_dt = self._inv_dt
        rv = [(x - x0) * inv_dt for x, x0 in zip(samples, previous[0])]
        ra = [(x - x0) * inv_dt for x, x0 in zip(rv, previous[1])]
        self._ref = (samples, rv, ra)
        if all(ok):
            return self._commit(r, samples, None, None, PASS)
        q, tv, ta = samples.copy(), self._tv.copy(), self._ta.copy()
        mode = [PASS if fit else ABSOLUTE for fit in ok]
        recovering = [j for j, (fit, m) in enumerate(zip(ok, self.mode)) if not fit and m in (OFFSET, ABSOLUTE)]
        if recovering and self._offset(rv, ra, previous):
            out = self._out
            cand = [x + e for x, e in zip(samples, out.new_position)]
            fits, ev, ea = self._fits(cand)[0], out.new_velocity, out.new_acceleration
            for j in recovering:
                if fits[j]:
                    q[j], mode[j], tv[j], ta[j] = cand[j], OFFSET, ev[j] + rv[j], ea[j] + ra[j]
        rest = [j for j, m in enumerate(mode) if m == ABSOLUTE]
        if rest:
            if not self._absolute(samples, rv):
                return self.stop()
            out = self._out
            nq, nv, na = out.new_position, out.new_velocity, out.new_acceleration
            brake = []
            for j in rest:
                q[j], tv[j], ta[j] = nq[j], nv[j], na[j]
                if not self._stop_fits(j, nq[j], nv[j], na[j]):  # heading past a soft limit: brake this joint
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
    def _handover(self, offset: bool = False) -> tuple[list[float], list[float]]:
        """ruckig's start state: its own where the same kind of plan drove the joint last tick,
        else what the samples imply (velocity at the end of the last tick). A replanning tracker
        must start from its own state: restarting from a lagging estimate each tick makes it
        overshoot. An offset state rides on the reference's estimated derivatives, so a plan on
        absolute positions starts from the samples instead.
        """
        half_dt, v, a = 0.5 * self.dt, [], []
        for m, own_v, own_a, sv, sa, v_max, a_max in zip(self.mode, self._tv, self._ta, *self.samples[1:],
                                                         self._vmax_f, self._amax_f):
            vj, aj = (own_v, own_a) if (m != PASS if offset else m >= ABSOLUTE) else (sv + sa * half_dt, sa)
            if not offset:
                vj, aj = min(max(vj, -v_max), v_max), min(max(aj, -a_max), a_max)
            v.append(vj)
            a.append(aj)
        return v, a

    def _brake(self) -> bool:
        inp = self._stop_in
        v, a = self._handover()
        inp.current_position, inp.current_velocity, inp.current_acceleration = self.samples[0], v, a
        return self._step(inp)

    def _absolute(self, r: list[float], rv: list[float]) -> bool:
        """ruckig's velocity interface toward the velocity that closes on the reference sample.

        Target velocity: the sample's velocity plus ``GAIN`` times the position error (the
        sample clipped to the soft limits), within the limit. A position target with the
        sample's velocity as target state would be time-optimal for a *fixed* target, and may
        back away first to get a run-up; a moving target makes that run-up permanent.
        """
        inp = self._absolute_in
        v, a = self._handover()
        p = self.samples[0]
        inp.current_position, inp.current_velocity, inp.current_acceleration = p, v, a
        target = [min(max(x, lo), hi) for x, lo, hi in zip(r, self._lo_f, self._hi_f)]
        closing = [(x_v if t == x else 0.0) + GAIN * (t - pj) for t, x, x_v, pj in zip(target, r, rv, p)]
        inp.target_velocity = [min(max(c, -v_max), v_max) * 0.99 for c, v_max in zip(closing, self._vmax_f)]
        return self._step(inp)

    def _offset(self, rv: list[float], ra: list[float], previous: tuple) -> bool:
        """ruckig on the error e = setpoint - reference, from its state now to zero."""
        v, a = self._handover(offset=True)
        inp = self._offset_in
        r0, rv0, ra0 = previous
        inp.current_position = [x - y for x, y in zip(self.samples[0], r0)]
        inp.current_velocity = [x - y for x, y in zip(v, rv0)]
        inp.current_acceleration = [x - y for x, y in zip(a, ra0)]
        v_floor, a_floor, j_floor = self._floors
        inp.max_velocity = [max(m - abs(x), f) for m, x, f in zip(self._vmax_f, rv, v_floor)]
        inp.max_acceleration = [max(m - abs(x), f) for m, x, f in zip(self._amax_f, ra, a_floor)]
        inv_dt = self._inv_dt
        inp.max_jerk = [max(m - abs(x - x0) * inv_dt, f) for m, x, x0, f in zip(self._jmax_f, ra, ra0, j_floor)]
        return self._step(inp)

    def _step(self, inp) -> bool:
        otg, self._out = self._otg[id(inp)]
        try:
            result = otg.update(inp, self._out)
        except (ruckig.RuckigError, ValueError) as exc:  # ValueError: a result code the binding does not name
            self.failed = failure_text(exc)
            otg.reset()
            return False
        return result in _PLANNED

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


def failure_text(exc: Exception) -> str:
    """ruckig's error as one line; a result code the binding does not name gets its name from result.hpp."""
    text = str(exc).strip().splitlines()[0]
    name = _UNNAMED.get(text.split(" ", 1)[0])
    return f"{name} (result {text.split(' ', 1)[0]})" if name else text
