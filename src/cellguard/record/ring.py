"""The pre-trigger ring: the last seconds of ticks at full servo rate, kept in preallocated arrays.

Every tick lands here (one row copy, no allocation); the recorder cuts the decimated stream
and, around an event, the full-rate stream out of it in batches. Ticks are numbered from 0 for
the whole run, so a tick index says both where it is in the ring and whether it is still there.
"""

from __future__ import annotations

import numpy as np

from cellguard.record.schemas import TICK_FIELDS


class TickRing:
    """Rows (t_ns, cycle, q_ref, q_cmd, q_meas, qd_meas, effort, current) for the last ``capacity`` ticks."""

    def __init__(self, dof: int, capacity: int):
        self.capacity = capacity
        self.t_ns = np.zeros(capacity, dtype=np.int64)
        self.cycle = np.zeros(capacity, dtype=np.int32)
        self.values = np.zeros((capacity, len(TICK_FIELDS), dof), dtype=np.float32)  # [tick, field, joint]
        self.n = 0  # ticks added since the start

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
        return max(0, self.n - self.capacity)

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
