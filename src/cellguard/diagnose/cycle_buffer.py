"""The ticks of the cycle in progress, kept in preallocated arrays on the servo path.

Per-cycle features are computed from this buffer when the cycle ends (not by rescanning the
record later), so diagnosis over months reads one row per cycle. On wall time a cycle's end is a
gap in the servo loop, so the rows are folded into per-block sums as they come (``BLOCK`` rows at
a time, one fold every ``BLOCK`` ticks): the end folds only the rows since the last whole block,
and its cost does not grow with the cycle's length (a 60 s cycle's features took 4 to 6 ms there).
"""

from __future__ import annotations

import numpy as np

from cellguard.robot.state import State

BLOCK = 512  # rows folded at a time [ticks]: a fold is a few numpy reductions over this many rows
# what each block's row of ``sums`` holds, per joint: max |current| [A], sum of current² [A²],
# sum of tracking error² [rad²], max |tracking error| [rad], sum |qd| [rad/s], sum effort·qd [W]
CURRENT_PEAK, CURRENT_SQ, ERROR_SQ, ERROR_MAX, TRAVEL, WORK = range(6)
_ROWS = ("t_ns", "reference", "setpoint", "q", "qd", "effort", "current")


class CycleBuffer:
    """Rows of (t, reference, setpoint, q, qd, effort, current) for up to ``capacity`` ticks, and their
    per-block sums: ``sums`` Shape (blocks, 6, dof), ``t_range`` the earliest and latest stamp of each
    block [ns] Shape (blocks, 2); block k holds rows ``k * BLOCK`` up to ``min((k + 1) * BLOCK, n)``."""

    def __init__(self, dof: int, capacity: int):
        self.t_ns = np.zeros(capacity, dtype=np.int64)
        self.reference = np.zeros((capacity, dof))
        self.setpoint = np.zeros((capacity, dof))
        self.q = np.zeros((capacity, dof))
        self.qd = np.zeros((capacity, dof))
        self.effort = np.zeros((capacity, dof))
        self.current = np.zeros((capacity, dof))
        self.sums = np.zeros((capacity // BLOCK + 1, 6, dof))
        self.t_range = np.zeros((capacity // BLOCK + 1, 2), dtype=np.int64)
        self._ones, self._scratch = np.ones(BLOCK), np.empty((dof, BLOCK))  # the fold's, allocated once
        self.n = 0

    def clear(self) -> None:
        self.n = 0

    def add(self, reference: np.ndarray, setpoint: np.ndarray, state: State) -> None:
        """Append one tick; every ``BLOCK`` th folds the block it completes. Past capacity (a cycle a recovery
        kept going past the time-out: an operator's hold) the arrays double, one copy of a few MB on that tick,
        so the cycle's features cover all of it."""
        i = self.n
        if i >= len(self.t_ns):
            self._grow()
        self.t_ns[i] = state.t_ns
        self.reference[i] = reference
        self.setpoint[i] = setpoint
        self.q[i] = state.q
        self.qd[i] = state.qd
        self.effort[i] = state.effort
        self.current[i] = state.current
        self.n = i = i + 1
        if not i % BLOCK:
            self._fold(i - BLOCK, i)

    def fold_rest(self) -> int:
        """Fold the rows after the last whole block (at the cycle's end); return how many: fewer than ``BLOCK``."""
        start = self.n - self.n % BLOCK
        if start < self.n:
            self._fold(start, self.n)
        return self.n - start

    @property
    def blocks(self) -> int:
        """Blocks that hold rows, the last one possibly partial (folded by ``fold_rest``)."""
        return -(-self.n // BLOCK)

    def _fold(self, a: int, b: int) -> None:
        """Rows ``a`` to ``b`` (one block) into that block's sums and stamp range. Column sums are a product with
        ones (BLAS) and maxima are taken along a transposed copy: numpy's reductions down the columns of a
        (BLOCK, dof) slice took 3 to 5 times as long (a fold 52 µs, now about 20)."""
        row, ones, scratch = self.sums[a // BLOCK], self._ones[:b - a], self._scratch[:, :b - a]
        current, qd = self.current[a:b], self.qd[a:b]
        error = self.setpoint[a:b] - self.q[a:b]
        np.dot(ones, current * current, out=row[CURRENT_SQ])
        np.dot(ones, error * error, out=row[ERROR_SQ])
        np.dot(ones, np.abs(qd), out=row[TRAVEL])
        np.dot(ones, self.effort[a:b] * qd, out=row[WORK])
        np.abs(current.T, out=scratch).max(axis=1, out=row[CURRENT_PEAK])
        np.abs(error.T, out=scratch).max(axis=1, out=row[ERROR_MAX])
        t = self.t_ns[a:b]
        self.t_range[a // BLOCK] = t.min(), t.max()

    def _grow(self) -> None:
        for name in (*_ROWS, "sums", "t_range"):
            old = getattr(self, name)
            new = np.zeros((2 * len(old), *old.shape[1:]), dtype=old.dtype)
            new[:len(old)] = old
            setattr(self, name, new)
