"""Executor: action chunks in, a time-indexed joint reference out, at every servo tick.

The newest valid chunk wins. Its steps that lie in the past when it arrives are dropped, not
replayed; between the reference at the switch and the chunk's first step still ahead, the
reference is interpolated linearly, so position stays continuous across chunk boundaries.
"""

from __future__ import annotations

import numpy as np

from cellguard.control.events import Event
from cellguard.embodiment import Profile
from cellguard.policy.chunk import ActionChunk


class Executor:
    """Holds the active chunk and answers ``reference(t_ns)``; validates chunks at its edge."""

    def __init__(self, profile: Profile, q0: np.ndarray):
        self.profile = profile
        self._times = np.zeros(1, dtype=np.int64)
        self._points = np.asarray(q0, dtype=np.float64).reshape(1, -1).copy()
        self.last_chunk_ns: int | None = None

    def push(self, chunk: ActionChunk, t_ns: int) -> list[Event]:
        """Take ``chunk`` at ``t_ns``; a malformed or fully stale chunk is refused with an event."""
        problem = self._check(chunk)
        if problem is not None:
            return [Event(t_ns, "chunk_rejected", problem)]
        times = chunk.t_obs_ns + (np.arange(chunk.horizon, dtype=np.int64) + 1) * chunk.dt_ns
        ahead = times > t_ns
        if not ahead.any():
            return [Event(t_ns, "chunk_stale", f"all {chunk.horizon} steps lie before now")]
        now = self.reference(t_ns)
        self._times = np.concatenate([[t_ns], times[ahead]])
        self._points = np.vstack([now, np.asarray(chunk.actions, dtype=np.float64)[ahead]])
        self.last_chunk_ns = t_ns
        dropped = int((~ahead).sum())
        return [Event(t_ns, "chunk_steps_dropped", f"{dropped} steps already past")] if dropped else []

    def reference(self, t_ns: int) -> np.ndarray:
        """The joint reference at ``t_ns``: interpolated inside the chunk, held after its end."""
        times = self._times
        if t_ns >= times[-1]:
            return self._points[-1].copy()
        k = int(np.searchsorted(times, t_ns, side="right"))
        if k == 0:
            return self._points[0].copy()
        u = (t_ns - times[k - 1]) / (times[k] - times[k - 1])
        return self._points[k - 1] + u * (self._points[k] - self._points[k - 1])

    def _check(self, chunk: ActionChunk) -> str | None:
        actions = chunk.actions
        if not isinstance(actions, np.ndarray) or actions.ndim != 2:
            return f"actions must be a 2-D array (H, {self.profile.dof}), got shape {np.shape(actions)}"
        if actions.shape[0] == 0 or actions.shape[1] != self.profile.dof:
            return f"actions shape {actions.shape} does not match (H>0, {self.profile.dof})"
        if not np.isfinite(actions).all():
            bad = np.argwhere(~np.isfinite(actions))[0]
            return f"non-finite action at step {bad[0]}, joint {self.profile.joint_names[bad[1]]}"
        if chunk.dt_ns <= 0:
            return f"dt_ns must be positive, got {chunk.dt_ns}"
        return None
