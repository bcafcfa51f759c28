"""Per-cycle features: the numbers a technician compares between a good and a faulted cycle.

Computed once, when the cycle ends, from the cycle's ticks (their per-block sums: ``CycleBuffer``; the end
reads the rows themselves only in the last block and in the two blocks a carry window's edges cut), its
chunks' latencies, its events and the cell's own outcome (grasp pose, camera readings). Names are flat and stable
(``current_peak.elbow``, ``grasp_offset_x_mm``) so that they become Parquet columns as they are.
"""

from __future__ import annotations

import numpy as np

from cellguard.control.events import NO_INTERVENTION, Event, EventKind
from cellguard.diagnose.cycle_buffer import (BLOCK, CURRENT_PEAK, CURRENT_SQ, ERROR_MAX, ERROR_SQ, TRAVEL, WORK,
                                             CycleBuffer)
from cellguard.embodiment import Profile

_XYZ = ("x", "y", "z")


def cycle_features(
    profile: Profile,
    ticks: CycleBuffer,
    outcome: dict,
    latencies_ns: list[int],
    events: list[Event],
) -> dict[str, float]:
    """Flat name -> value features of one cycle (SI unless the name says ``_mm`` or ``_ms``). A cycle whose ticks
    the buffer could not all hold (``ticks.dropped``: out of memory) has none from its ticks (no reading, NaN in the
    diagnosis): read from its start only, a healthy cell's currents were a load change."""
    ticks.fold_rest()
    sums = ticks.sums[:ticks.blocks]
    f: dict[str, float] = {}
    if not ticks.dropped:
        _tick_features(f, profile, ticks, sums)
    f["latency_mean_ms"] = float(np.mean(latencies_ns)) * 1e-6 if latencies_ns else 0.0
    f["latency_max_ms"] = float(np.max(latencies_ns)) * 1e-6 if latencies_ns else 0.0
    f["interventions"] = float(sum(e.kind not in NO_INTERVENTION for e in events))
    f["chunks_rejected"] = float(sum(e.kind == EventKind.CHUNK_REJECTED for e in events))
    f["stale_chunks"] = float(sum(e.kind in (EventKind.CHUNK_STEPS_DROPPED, EventKind.CHUNK_STALE) for e in events))
    for key, value in outcome.items():
        _flatten(f, key, value, profile)
    if not ticks.dropped:
        _carry_currents(f, profile, ticks, outcome)
    return f


def _tick_features(f: dict[str, float], profile: Profile, ticks: CycleBuffer, sums: np.ndarray) -> None:
    """Each joint's current and tracking peaks and RMS, and its friction torque, from the block sums."""
    n = ticks.n
    if n:
        peak, tracking_max = sums[:, CURRENT_PEAK].max(axis=0), sums[:, ERROR_MAX].max(axis=0)
        current_rms = np.sqrt(sums[:, CURRENT_SQ].sum(axis=0) / n)
        tracking_rms = np.sqrt(sums[:, ERROR_SQ].sum(axis=0) / n)
    for j, name in enumerate(profile.joint_names):
        f[f"current_peak.{name}"] = float(peak[j]) if n else 0.0
        f[f"current_rms.{name}"] = float(current_rms[j]) if n else 0.0
        f[f"tracking_rms.{name}"] = float(tracking_rms[j]) if n else 0.0
        f[f"tracking_max.{name}"] = float(tracking_max[j]) if n else 0.0
    _friction_torques(f, profile, ticks, sums)


MIN_TRAVEL = 0.05  # [rad] a joint that moved less than this in a cycle has no friction estimate


def _friction_torques(f: dict[str, float], profile: Profile, ticks: CycleBuffer, sums: np.ndarray) -> None:
    """Per joint, the torque that opposed its motion over the cycle [N·m]: the work its drive did
    (sum of effort x velocity) over the distance it travelled (sum of |velocity|). Over a cycle that
    returns to its start, gravity and inertia give back what they took, so this is dry friction
    plus the viscous share. The motor current does not show it on a loaded joint: friction adds to
    the load on one stroke and subtracts on the other, and its RMS barely moves."""
    n = ticks.n
    if not n:
        return
    travel, work = sums[:, TRAVEL].sum(axis=0), sums[:, WORK].sum(axis=0)
    dt = (ticks.stamp(n - 1) - ticks.stamp(0)) * 1e-9 / max(n - 1, 1)
    for j, name in enumerate(profile.joint_names):
        if travel[j] * dt >= MIN_TRAVEL:
            f[f"friction_torque.{name}"] = float(work[j] / travel[j])


def _carry_currents(f: dict[str, float], profile: Profile, ticks: CycleBuffer, outcome: dict) -> None:
    """RMS current per joint while carrying a part (grasp to release) and while not: a load change
    moves only the first, friction both."""
    n = ticks.n
    grasp, release = outcome.get("grasp_time_s"), outcome.get("release_time_s")
    if not n or not outcome.get("grasped") or grasp is None or release is None:
        return
    (carry_sq, carried), (free_sq, free) = _split_current_sq(ticks, grasp, release)
    if carried < 2 or free < 2:
        return
    carry_rms, free_rms = np.sqrt(carry_sq / carried), np.sqrt(free_sq / free)
    for j, name in enumerate(profile.joint_names):
        f[f"current_carry_rms.{name}"] = float(carry_rms[j])
        f[f"current_free_rms.{name}"] = float(free_rms[j])


def _split_current_sq(ticks: CycleBuffer, grasp: float, release: float) -> tuple[tuple, tuple]:
    """(sum of current² [A²] per joint, ticks) inside ``grasp <= t < release`` [s from the first tick] and outside:
    a block wholly on one side by its sums, a block the window's edges cut (two, the stamps in order) by its rows.
    ``fold_rest`` has run."""
    n, t0, nb = ticks.n, ticks.stamp(0), ticks.blocks
    sums, (lo, hi) = ticks.sums[:nb, CURRENT_SQ], ((ticks.t_range[:nb] - t0) * 1e-9).T
    rows = np.minimum(BLOCK, n - np.arange(nb) * BLOCK)
    inside, outside = (lo >= grasp) & (hi < release), (hi < grasp) | (lo >= release)
    carry_sq, free_sq = sums[inside].sum(axis=0), sums[outside].sum(axis=0)
    carried, free = int(rows[inside].sum()), int(rows[outside].sum())
    for k in np.flatnonzero(~inside & ~outside):
        t = (ticks.block("t_ns", k) - t0) * 1e-9
        carry = (t >= grasp) & (t < release)
        square = ticks.block("current", k) ** 2
        carry_sq, free_sq = carry_sq + square[carry].sum(axis=0), free_sq + square[~carry].sum(axis=0)
        carried, free = carried + int(carry.sum()), free + int((~carry).sum())
    return (carry_sq, carried), (free_sq, free)


def _flatten(f: dict[str, float], key: str, value, profile: Profile) -> None:
    if isinstance(value, bool):
        f[key] = float(value)
    elif isinstance(value, (int, float)):
        f[key] = float(value)
    elif key.endswith("_q") and isinstance(value, list) and len(value) == profile.dof:
        for name, v in zip(profile.joint_names, value):
            f[f"{key}.{name}"] = float(v)
    elif isinstance(value, list) and len(value) == 3 and all(isinstance(v, (int, float)) for v in value):
        stem, unit = key.rsplit("_", 1) if "_" in key else (key, "")
        scale = 1e3 if unit == "m" else 1.0
        unit = "mm" if unit in ("m", "mm") else unit
        for axis, v in zip(_XYZ, value):
            f[f"{stem}_{axis}_{unit}" if unit else f"{stem}_{axis}"] = float(v) * scale
