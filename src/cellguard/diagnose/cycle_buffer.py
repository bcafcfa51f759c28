"""The ticks of the cycle in progress, kept in fixed-size chunks on the servo path.

Per-cycle features are computed from this buffer when the cycle ends (not by rescanning the
record later), so diagnosis over months reads one row per cycle. On wall time a cycle's end is a
gap in the servo loop, so the rows are folded into per-block sums as they come (``BLOCK`` rows at
a time, one fold every ``BLOCK`` ticks): the end folds only the rows since the last whole block,
and its cost does not grow with the cycle's length (a 60 s cycle's features took 4 to 6 ms there).

The rows go into chunks of whole blocks, one more allocated when the last is full and kept for the
next cycles: what is stored is never copied on the servo path (doubling the arrays mid-cycle copied them
on one tick: 22 ms), and a long cycle's limit is not reserved up front (a 3,600 s time cycle on
the quadruped reserved 2 GB of address space, refused under a ``ulimit -v`` or ``overcommit_memory=2``).
A chunk that cannot be allocated ends the buffer's growth for the cycle, not the run: it keeps its first
rows and counts the rest (``dropped``); a MemoryError on the servo path ended a 3,600 s cycle 819 s in.
"""

from __future__ import annotations

import numpy as np

from cellguard.robot.state import State

BLOCK = 512  # rows folded at a time [ticks]: a fold is a few numpy reductions over this many rows
CHUNK_BLOCKS = 64  # the most blocks in a chunk: 32,768 ticks, 19 MB for 12 joints (33 s at 1 kHz)
# what each block's row of ``sums`` holds, per joint: max |current| [A], sum of current² [A²],
# sum of tracking error² [rad²], max |tracking error| [rad], sum |qd| [rad/s], sum effort·qd [W]
CURRENT_PEAK, CURRENT_SQ, ERROR_SQ, ERROR_MAX, TRAVEL, WORK = range(6)
COLUMNS = ("t_ns", "reference", "setpoint", "q", "qd", "effort", "current")


class _Chunk:
    """``blocks * BLOCK`` rows of each column and the sums and stamp range of each of its blocks."""

    __slots__ = (*COLUMNS, "sums", "t_range")

    def __init__(self, dof: int, blocks: int):
        rows = blocks * BLOCK
        self.t_ns = np.empty(rows, dtype=np.int64)
        for name in COLUMNS[1:]:
            setattr(self, name, np.empty((rows, dof)))
        self.sums = np.empty((blocks, 6, dof))
        self.t_range = np.empty((blocks, 2), dtype=np.int64)


class CycleBuffer:
    """Rows of (t, reference, setpoint, q, qd, effort, current) and their per-block sums. ``capacity``: the ticks a
    cycle may hold before its time-out; a chunk holds that many in whole blocks, up to ``CHUNK_BLOCKS`` (so a cycle
    that short is read back as views), and a longer one (a long time cycle, a recovery's hold) takes more chunks.
    Block k holds rows ``k * BLOCK`` up to ``min((k + 1) * BLOCK, n)``; no block spans two chunks."""

    def __init__(self, dof: int, capacity: int):
        self.dof, self.chunk_blocks = dof, min(max(-(-capacity // BLOCK), 1), CHUNK_BLOCKS)
        self.chunk_rows = self.chunk_blocks * BLOCK
        self._chunks = [_Chunk(dof, self.chunk_blocks)]
        self._ones, self._scratch = np.ones(BLOCK), np.empty((dof, BLOCK))  # the fold's, allocated once
        self.n = self.dropped = 0  # the rows held, and those not held once a chunk could not be allocated
        self._at, self._start = self._chunks[0], 0  # the chunk the next row goes to, and its first row's index

    def clear(self) -> None:
        self.n = self.dropped = 0
        self._at, self._start = self._chunks[0], 0

    def add(self, reference: np.ndarray, setpoint: np.ndarray, state: State) -> bool:
        """Append one tick; every ``BLOCK`` th folds the block it completes. False where it is not held: the cycle
        filled its chunks and no more memory could be had for the next (``dropped`` counts those; not retried
        before ``clear``, so a full buffer costs a tick nothing)."""
        r = self.n - self._start
        if r == self.chunk_rows:
            if self.dropped or not self._next_chunk():
                self.dropped += 1
                return False
            r = 0
        c = self._at
        c.t_ns[r] = state.t_ns
        c.reference[r] = reference
        c.setpoint[r] = setpoint
        c.q[r] = state.q
        c.qd[r] = state.qd
        c.effort[r] = state.effort
        c.current[r] = state.current
        self.n += 1
        r += 1
        if not r % BLOCK:
            self._fold(c, r - BLOCK, r)
        return True

    def fold_rest(self) -> int:
        """Fold the rows after the last whole block (at the cycle's end); return how many: fewer than ``BLOCK``."""
        rest = self.n % BLOCK
        if rest:
            b = self.n - self._start
            self._fold(self._at, b - rest, b)
        return rest

    @property
    def blocks(self) -> int:
        """Blocks that hold rows, the last one possibly partial (folded by ``fold_rest``)."""
        return -(-self.n // BLOCK)

    @property
    def sums(self) -> np.ndarray:
        """Each block's sums, Shape (blocks, 6, dof): the last one's once ``fold_rest`` has run."""
        return self._joined("sums", self.blocks, self.chunk_blocks)

    @property
    def t_range(self) -> np.ndarray:
        """Each block's earliest and latest stamp [ns] Shape (blocks, 2)."""
        return self._joined("t_range", self.blocks, self.chunk_blocks)

    def rows(self, name: str) -> np.ndarray:
        """The cycle's rows of column ``name`` (of ``COLUMNS``), Shape (n,) or (n, dof): a view while they fit in
        one chunk, else a copy, made at the cycle's end, never on the servo path, and not cheap for a long cycle:
        1,000 s of 12 joints is 92 MiB and about 240 to 290 ms a column with fresh pages, 15 ms with warm ones."""
        return self._joined(name, self.n, self.chunk_rows)

    def block(self, name: str, k: int) -> np.ndarray:
        """The rows of block ``k`` of column ``name``: a view."""
        a = (k % self.chunk_blocks) * BLOCK
        return getattr(self._chunks[k // self.chunk_blocks], name)[a:a + min(BLOCK, self.n - k * BLOCK)]

    def stamp(self, i: int) -> int:
        """Tick ``i``'s stamp [ns], ``0 <= i < n``."""
        return int(self._chunks[i // self.chunk_rows].t_ns[i % self.chunk_rows])

    def _next_chunk(self) -> bool:
        """Move on to the next chunk, allocated the first time a cycle fills the ones before: no copy, about
        35 µs for a whole chunk of 12 joints, once in 32,768 ticks. False where it cannot be allocated."""
        k = self._start // self.chunk_rows + 1
        if k == len(self._chunks):
            try:
                self._chunks.append(_Chunk(self.dof, self.chunk_blocks))
            except MemoryError:  # under a memory limit (ulimit -v, a cgroup's): what is held is kept
                return False
        self._at, self._start = self._chunks[k], self._start + self.chunk_rows
        return True

    def _joined(self, name: str, count: int, per_chunk: int) -> np.ndarray:
        """The first ``count`` rows of array ``name`` over the chunks (``per_chunk`` rows each)."""
        parts = [getattr(c, name) for c in self._chunks[:max(1, -(-count // per_chunk))]]
        parts[-1] = parts[-1][:count - (len(parts) - 1) * per_chunk]
        return parts[0] if len(parts) == 1 else np.concatenate(parts)

    def _fold(self, c: _Chunk, a: int, b: int) -> None:
        """Rows ``a`` to ``b`` of chunk ``c`` (one block) into that block's sums and stamp range. Column sums are a
        product with ones (BLAS) and maxima are taken along a transposed copy: numpy's reductions down the columns
        of a (BLOCK, dof) slice took 3 to 5 times as long (a fold 52 µs, now about 20)."""
        row, ones, scratch = c.sums[a // BLOCK], self._ones[:b - a], self._scratch[:, :b - a]
        current, qd = c.current[a:b], c.qd[a:b]
        error = c.setpoint[a:b] - c.q[a:b]
        np.dot(ones, current * current, out=row[CURRENT_SQ])
        np.dot(ones, error * error, out=row[ERROR_SQ])
        np.dot(ones, np.abs(qd), out=row[TRAVEL])
        np.dot(ones, c.effort[a:b] * qd, out=row[WORK])
        np.abs(current.T, out=scratch).max(axis=1, out=row[CURRENT_PEAK])
        np.abs(error.T, out=scratch).max(axis=1, out=row[ERROR_MAX])
        t = c.t_ns[a:b]
        c.t_range[a // BLOCK] = t.min(), t.max()
