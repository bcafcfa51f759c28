"""The ticks of the cycle in progress, kept in preallocated arrays on the servo path.

Per-cycle features are computed from this buffer when the cycle ends (not by rescanning the
record later), so diagnosis over months reads one row per cycle.
"""

from __future__ import annotations

import numpy as np

from cellguard.robot.state import State


class CycleBuffer:
    """Rows of (t, reference, setpoint, q, qd, effort, current) for up to ``capacity`` ticks."""

    def __init__(self, dof: int, capacity: int):
        self.t_ns = np.zeros(capacity, dtype=np.int64)
        self.reference = np.zeros((capacity, dof))
        self.setpoint = np.zeros((capacity, dof))
        self.q = np.zeros((capacity, dof))
        self.qd = np.zeros((capacity, dof))
        self.effort = np.zeros((capacity, dof))
        self.current = np.zeros((capacity, dof))
        self.n = 0

    def clear(self) -> None:
        self.n = 0

    def add(self, reference: np.ndarray, setpoint: np.ndarray, state: State) -> None:
        """Append one tick. Past capacity (a cycle a recovery kept going past the time-out: an operator's hold)
        the arrays double, one copy of a few MB on that tick, so the cycle's features cover all of it."""
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
        self.n = i + 1

    def _grow(self) -> None:
        for name in ("t_ns", "reference", "setpoint", "q", "qd", "effort", "current"):
            old = getattr(self, name)
            new = np.zeros((2 * len(old), *old.shape[1:]), dtype=old.dtype)
            new[:len(old)] = old
            setattr(self, name, new)
