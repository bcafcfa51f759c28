"""What the gates keep of a run's chunks and ticks: reduced as its record is read.

A stage's gates read every run counted since its release became current. Held whole, each run's chunks and
ticks (about 230 kB a cycle on the arm) made an evaluation's memory grow with the stage's history; the metrics
that read them need only these reductions (the seams, the latencies, the ticks outside the limits), so a
counted run costs about its cycles' records.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from cellguard.record.reader import NO_CYCLE, RecordedChunk, Ticks

VELOCITY_MARGIN = 1.05  # a measured speed this far over the profile's limit counts as a violation (noise)


@dataclass(frozen=True)
class Chunks:
    """A run's chunks as the gates see them: each one's latency, and its seams (switches where both chunks
    name a target) with the largest step between them and when it was."""

    latency_ms: np.ndarray
    seams: int = 0
    worst_seam_mrad: float = 0.0
    worst_seam_t_ns: int | None = None  # None: no seam stepped at all


@dataclass(frozen=True)
class LimitTicks:
    """A run's recorded ticks outside the profile's position range or over its velocity limit: how many, and the
    first one's cycle (None: between cycles, e.g. in the retreat) and joint."""

    count: int = 0
    first_cycle: int | None = None
    joint: str | None = None


def reduce_chunks(chunks: Iterable[RecordedChunk]) -> Chunks:
    """One pass over the chunks in arrival order, holding two at a time. A seam is measured as received: at the
    incoming chunk's arrival, or at its first step where it arrives before it (no target of its own before then)."""
    latency, seams, worst, worst_t, old = [], 0, 0.0, None, None
    for new in chunks:
        latency.append(new.latency_ns * 1e-6)
        if old is not None:
            t = max(new.t_received_ns, new.t_obs_ns + new.dt_ns)
            a_old, a_new = action_at(old, t), action_at(new, t)
            if a_old is not None and a_new is not None:  # else the old one had ended, or the new one is all past
                jump = float(np.abs(a_new - a_old).max()) * 1e3
                seams += 1
                if jump > worst:
                    worst, worst_t = jump, t
        old = new
    return Chunks(np.asarray(latency, dtype=float), seams, worst, worst_t)


def action_at(chunk, t_ns: int):
    """The chunk's action at ``t_ns``, linear between its steps, step ``i`` due at ``t_obs + (i + 1) * dt``
    (``ActionChunk.step_times_ns``); None before its first step or past its last (it names no target there)."""
    n = len(chunk.actions)
    s = (t_ns - chunk.t_obs_ns) / chunk.dt_ns - 1  # in steps from the first
    if s < 0 or s > n - 1:
        return None
    if n == 1:
        return chunk.actions[0]
    i = min(int(s), n - 2)
    f = s - i
    return (1 - f) * chunk.actions[i] + f * chunk.actions[i + 1]


def limit_ticks(ticks: Ticks, profile) -> LimitTicks:
    """Measured positions outside ``profile``'s range or speeds over its velocity limit (with a noise margin)."""
    q, qd = ticks.q_meas, ticks.qd_meas
    bad = (q < profile.q_min) | (q > profile.q_max) | (np.abs(qd) > profile.array("velocity") * VELOCITY_MARGIN)
    rows = np.flatnonzero(bad.any(axis=1))
    if not len(rows):
        return LimitTicks()
    joint, cycle = int(np.flatnonzero(bad[rows[0]])[0]), int(ticks.cycle[rows[0]])
    return LimitTicks(len(rows), None if cycle == NO_CYCLE else cycle, profile.joint_names[joint])
