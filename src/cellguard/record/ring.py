"""The pre-trigger ring: the last seconds of ticks at full servo rate, kept in preallocated arrays.

Every tick lands here (one row copy, no allocation); the recorder cuts the decimated stream
and, around an event, the full-rate stream out of it in batches. Ticks are numbered from 0 for
the whole run, so a tick index says both where it is in the ring and whether it is still there.

A ring made with ``slack`` lives in memory shared with processes forked after it: the loop adds
rows, the writer process reads them, and the loop may run up to ``slack`` rows ahead of the
reader before it overwrites a row the reader still needs (``keep`` rows behind the reader's own
count stay valid).
"""

from __future__ import annotations

import mmap

import numpy as np

from cellguard.record.schemas import TICK_FIELDS


class TickRing:
    """Rows (t_ns, cycle, q_ref, q_cmd, q_meas, qd_meas, effort, current) for the last ``keep`` ticks."""

    def __init__(self, dof: int, keep: int, slack: int | None = None):
        self.keep, self.capacity = keep, keep + (slack or 0)
        shape = (self.capacity, len(TICK_FIELDS), dof)
        if slack is None:
            self.t_ns = np.zeros(self.capacity, dtype=np.int64)
            self.cycle = np.zeros(self.capacity, dtype=np.int32)
            self.values = np.zeros(shape, dtype=np.float32)  # [tick, field, joint]
        else:  # anonymous shared memory: a forked child sees the same pages
            sizes = (8 * self.capacity, 4 * self.capacity, 4 * int(np.prod(shape)))
            self._memory = memory = mmap.mmap(-1, sum(sizes))
            # every page mapped now (a first touch per 4 KB on the servo thread cost µs), in place: zeros written from
            # a buffer of the ring's size took that much memory again at the start
            np.frombuffer(memory, np.uint8).fill(0)
            self.t_ns = np.frombuffer(memory, np.int64, self.capacity, 0)
            self.cycle = np.frombuffer(memory, np.int32, self.capacity, sizes[0])
            self.values = np.frombuffer(memory, np.float32, int(np.prod(shape)), sizes[0] + sizes[1]).reshape(shape)
        self.n = 0  # ticks added since the start (in a reader: ticks it has taken)

    def add(self, t_ns: int, cycle: int, reference, sent, q, qd, effort, current) -> None:
        i = self.n % self.capacity
        self.t_ns[i] = t_ns
        self.cycle[i] = cycle
        row = self.values[i]
        row[0] = reference
        row[1] = sent
        row[2] = q
        row[3] = qd
        row[4] = effort
        row[5] = current
        self.n += 1

    @property
    def oldest(self) -> int:
        """Index of the oldest tick still held."""
        return max(0, self.n - self.keep)

    def last_t_ns(self) -> int:
        return int(self.t_ns[(self.n - 1) % self.capacity]) if self.n else -1

    def batch(self, start: int, stop: int, step: int = 1) -> dict:
        """Ticks ``start, start+step, ... < stop`` (all still held) as TickBatch fields."""
        idx = np.arange(start, stop, step) % self.capacity
        values = self.values[idx]
        out = {"t_ns": self.t_ns[idx], "cycle": self.cycle[idx]}
        for k, name in enumerate(TICK_FIELDS):
            out[name] = values[:, k, :]
        return out
