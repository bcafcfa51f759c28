"""ActionChunk: what every policy source returns, in this robot's joint order and SI units."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MAX_HORIZON = 1000  # steps; the executor refuses a longer chunk as malformed


@dataclass(frozen=True)
class ActionChunk:
    """H joint targets answering the observation taken at ``t_obs_ns``.

    ``actions`` has shape (H, D); step ``i`` is the target for ``t_obs_ns + (i + 1) * dt_ns``.
    ``uncertainty`` (H,) is optional, in the policy's own scale (the envelope's gate sets the
    threshold). The chunk is not validated here: the executor checks it at its edge, so a bad
    chunk becomes an event, never an exception on the servo path.
    """

    actions: np.ndarray
    t_obs_ns: int
    dt_ns: int
    uncertainty: np.ndarray | None = None

    @property
    def horizon(self) -> int:
        return int(np.shape(self.actions)[0]) if np.ndim(self.actions) >= 1 else 0

    def step_times_ns(self) -> np.ndarray:
        """(H,) int64: when each step is due [ns]."""
        return self.t_obs_ns + (np.arange(self.horizon, dtype=np.int64) + 1) * self.dt_ns
