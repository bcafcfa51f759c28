"""A chunk's steps as one C2 curve: a not-a-knot cubic spline on uniform knots.

The servo loop samples a chunk at 1 kHz between steps 10 to 50 ms apart. Linear interpolation
would step the velocity at every knot (an acceleration spike of Δv/1 ms) and a C1 curve would
step the acceleration (a jerk spike); a cubic spline is C2, so velocity and acceleration are
continuous and the jerk is piecewise constant. Not-a-knot end conditions keep the first
segments accurate, which matters because the executor plays a chunk mostly near its start.
The coefficients are computed once per chunk (off the servo path); evaluation is a Horner step.
"""

from __future__ import annotations

import copy
from functools import lru_cache

import numpy as np


@lru_cache(maxsize=64)
def _second_derivative_map(n: int) -> np.ndarray:
    """Matrix K with M = K @ y / h²: knot second derivatives of the not-a-knot spline, shape (n, n)."""
    a = np.zeros((n, n))
    b = np.zeros((n, n))
    for i in range(1, n - 1):
        a[i, i - 1:i + 2] = (1.0, 4.0, 1.0)
        b[i, i - 1:i + 2] = (6.0, -12.0, 6.0)
    a[0, 0:3] = (1.0, -2.0, 1.0)  # third derivative continuous across knot 1
    a[n - 1, n - 3:n] = (1.0, -2.0, 1.0)  # and across knot n-2
    k = np.linalg.solve(a, b)
    k.setflags(write=False)
    return k


class ChunkCurve:
    """Cubic through ``points`` (n, D) at ``t0_ns + i * h_ns``; held at the ends beyond the knots.

    ``coefficients`` has shape (n-1, 4, D): position, velocity, acceleration/2 and jerk/6 of
    each segment at its start, in [rad] or [m] per seconds^k.
    """

    def __init__(self, t0_ns: int, h_ns: int, points: np.ndarray):
        self.t0_ns, self.h_ns = int(t0_ns), int(h_ns)
        self.points = points
        self.end_ns = self.t0_ns + (len(points) - 1) * self.h_ns
        self._h = h_ns * 1e-9
        self.coefficients = self._fit(points, self._h)

    def shifted(self, t0_ns: int) -> ChunkCurve:
        """The same curve starting at ``t0_ns`` (no refit)."""
        other = copy.copy(self)
        other.t0_ns, other.end_ns = int(t0_ns), int(t0_ns) + (len(self.points) - 1) * self.h_ns
        return other

    def state_at(self, t_ns: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity and half the acceleration (D,) at ``t_ns`` (before its end)."""
        k, u = self.segment(t_ns)
        c = self.coefficients[k]
        return np.dot((1.0, u, u * u, u * u * u), c), c[1] + u * (2.0 * c[2] + 3.0 * u * c[3]), c[2] + 3.0 * u * c[3]

    def less_motion(self, t_ns: int, q: np.ndarray, until_ns: int) -> ChunkCurve:
        """This curve less its position, velocity and acceleration at ``t_ns`` (before its end), plus ``q``: at rest
        at ``q`` there, then moving as the curve does beyond that quadratic; held past its end as ``at`` reads it.
        Only the segments from ``t_ns`` to ``until_ns`` are kept (the quadratic goes on where the curve holds): it is
        built on the servo tick that takes a chunk from rest."""
        if len(self.points) == 1:  # a hold (a one-step chunk, its step still ahead): less its position, a hold at q
            return ChunkCurve(t_ns, self.h_ns, np.asarray(q, dtype=np.float64)[None])
        q_at, v, half_a = self.state_at(t_ns)
        h = self.h_ns
        first = min(self.segment(t_ns)[0], len(self.points) - 1)
        t0 = self.t0_ns + first * h
        last = min(len(self.points) - 1, first + max(-(-(until_ns - t0) // h), 1))
        extra = max(-(-(until_ns - (self.t0_ns + last * h)) // h), 0)  # held segments past the end
        points = np.concatenate([self.points[first:last + 1], np.repeat(self.points[last:last + 1], extra, axis=0)])
        held = np.zeros((extra, 4, points.shape[1]))
        held[:, 0] = self.points[last]
        coefficients = np.concatenate([self.coefficients[first:last], held])
        d = ((t0 - t_ns + np.arange(len(points)) * h) * 1e-9)[:, None]  # each knot from t_ns [s]
        other = copy.copy(self)
        other.t0_ns = t0
        other.points = points - (q_at - q) - d * (v + d * half_a)
        other.end_ns = t0 + (len(points) - 1) * h
        other.coefficients = coefficients
        d = d[:-1]
        coefficients[:, 0] = other.points[:-1]
        coefficients[:, 1] -= v + 2.0 * d * half_a
        coefficients[:, 2] -= half_a
        return other

    @staticmethod
    def _fit(y: np.ndarray, h: float) -> np.ndarray:
        n = len(y)
        if n == 1:  # a hold: one constant segment
            y = np.vstack([y, y])
            n = 2
        if n == 2:
            m = np.zeros_like(y)
        elif n == 3:
            m = np.repeat(((y[0] - 2.0 * y[1] + y[2]) / (h * h))[None], 3, axis=0)
        else:
            m = _second_derivative_map(n) @ y / (h * h)
        c = np.empty((n - 1, 4, y.shape[1]))
        c[:, 0] = y[:-1]
        c[:, 1] = (y[1:] - y[:-1]) / h - h * (2.0 * m[:-1] + m[1:]) / 6.0
        c[:, 2] = m[:-1] / 2.0
        c[:, 3] = (m[1:] - m[:-1]) / (6.0 * h)
        return c

    def segment(self, t_ns: int) -> tuple[int, float]:
        """The segment at ``t_ns`` and the time into it [s] (the last one's end once held)."""
        if t_ns >= self.end_ns:
            return len(self.coefficients) - 1, self._h
        k = max((t_ns - self.t0_ns) // self.h_ns, 0)
        return k, (t_ns - self.t0_ns - k * self.h_ns) * 1e-9

    def at(self, t_ns: int) -> np.ndarray:
        """Position at ``t_ns``: the first segment extended before the first knot, held after the last."""
        if t_ns >= self.end_ns:
            return self.points[-1]
        k, u = self.segment(t_ns)
        return np.dot((1.0, u, u * u, u * u * u), self.coefficients[k])  # one call: cheaper than Horner on (D,)

    def at_times(self, t_ns: np.ndarray) -> np.ndarray:
        """Positions (n, D) at the times ``t_ns`` (n,), each as ``at`` reads it, in one evaluation (a push from
        rest samples a whole blend: one ``at`` per sample cost 11 ms for a 1 s blend of 1 ms steps)."""
        t = np.asarray(t_ns, dtype=np.int64)
        k = np.minimum(np.maximum((t - self.t0_ns) // self.h_ns, 0), len(self.coefficients) - 1)  # np.clip: 3x slower
        u = ((t - self.t0_ns - k * self.h_ns) * 1e-9)[:, None]
        c = self.coefficients[k]
        out = c[:, 0] + u * (c[:, 1] + u * (c[:, 2] + u * c[:, 3]))
        out[t >= self.end_ns] = self.points[-1]
        return out
