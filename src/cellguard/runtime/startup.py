"""Start-up checks that refuse to move, each with one line naming the dimension.

Run on the run's first chunk, before the robot moves: the observation lies inside the policy's
normalisation statistics (per-dimension q01..q99, widened by a margin of the range), when the
policy offers them as ``normalisation_stats() -> {name: (q01, q99)}`` (finite, q01 <= q99, one
per observed value, else refused too: NaN statistics compared false and passed; in the cell's units
and joint order, as the policy's adapter sees the observation; a name the cell does not observe is
refused, not skipped: the check never ran); and the next chunk arrives before this one ends (the
next observation's time after this one, plus the latency, plus one servo period < the horizon),
else the robot would run out of steps and the guard brake it at every chunk. A chunk is taken at
the tick after it is ready, up to one period later: a 2 Hz robot took every 500 ms chunk with all
its steps past, and did nothing. The next observation waits for this chunk (one request at a
time), the policy's period and, on a worker, until the chunk runs low (half its horizon, as
LeRobot's async client): counting the latency alone let through 298 ms on the scripted arm's
500 ms chunks in simulated time, at which every chunk ended before the next arrived. This also
refuses what the latency alone could not fit (latency at or over the horizon less the blend, the
blend at most half the horizon); a next chunk that arrives within the blend time of the end only
shortens the blend (continuous still, and guarded). The same spacing refuses a policy watchdog
(``guard.watchdog_s``) no longer than the time between chunks: the default 300 ms stopped the robot at every
chunk of a 1 s chunk policy on a worker (asked again half a chunk in), a stop and a resume each time. Its floor,
the policy's period plus one servo period, is known from the scenario and refused as the run is built, before its
record starts (``watchdog_refusal``): refused here only, an old record under ``--overwrite`` was replaced by one
holding the refusal alone.

A tool point that starts outside the workspace box (a robot left there, a sim-server cell posed there) is taken to
the first target, no further out: one inside the box grown wall by wall to hold the start (``BoxStart``, the
guard's ``grown_box``, as the approach's ``Transition.leaves_box`` and the guard's look-ahead let a motion from
outside do). A first target further out, or one whose approach goes further out on the way, is refused as a chunk is
(a learned policy's next may be fine; the approach refused the start, exit 2, for a target 34.8 mm over the ceiling
where 35.2 mm was allowed), and where every one is, the policy-lost line names the box start. Refused as the policy's
answer, every first chunk of a policy that held there or moved back in read as "policy lost: the guard rejected every
chunk".
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from cellguard.control.checks.workspace import at, box_excess, grown_box, mm
from cellguard.errors import ConfigError

STATS_MARGIN = 0.1  # fraction of q99 - q01 allowed outside the statistics' range


class StartupRefused(ConfigError):
    """A start-up check failed: the robot does not move."""


def check_startup(policy, observation, chunk, latency_ns: int, period_ns: int, spacing_ns: int | None = None,
                  watchdog_ns: int | None = None, margin: float = STATS_MARGIN) -> None:
    """Raise StartupRefused naming the first dimension out of range, a latency the chunk cannot cover or a
    watchdog the chunks cannot feed (``period_ns``: the servo period, the longest a ready chunk waits for its tick;
    ``spacing_ns``: the longest time from one observation to the next; None: until the chunk is taken, the least
    with one request at a time; ``watchdog_ns``: the policy-silence watchdog, None: not checked)."""
    stats = getattr(policy, "normalisation_stats", None)
    if callable(stats) and observation is not None:
        given = stats()
        if not isinstance(given, Mapping):
            raise StartupRefused(f"start-up: the policy's normalisation statistics must map names to (q01, q99), "
                                 f"got {type(given).__name__}; not moving")
        for name, pair in given.items():
            value = _observed(observation, name)
            if value is None:
                raise StartupRefused(f"start-up: the policy's normalisation statistics name {str(name)[:80]!r}, which "
                                     f"the cell does not observe (it observes: q, "
                                     f"{', '.join(observation.measurements) or 'nothing else'}); not moving")
            q01, q99 = _checked_stats(name, pair, value)
            with np.errstate(over="ignore"):  # statistics of 1e308 widen to inf: nothing is outside them
                pad = margin * (q99 - q01)
            out = np.flatnonzero((value < q01 - pad) | (value > q99 + pad))
            if out.size:
                i = int(out[0])
                raise StartupRefused(f"start-up: observation {name}[{i}] = {value[i]:.4g} is outside the policy's "
                                     f"normalisation range [{q01[i] - pad[i]:.4g}, {q99[i] + pad[i]:.4g}] "
                                     f"(q01..q99 with {margin:.0%} margin); not moving")
    horizon_ns = chunk.actions.shape[0] * chunk.dt_ns  # its last step is due this long after its observation
    taken_ns = latency_ns + period_ns
    spacing_ns = taken_ns if spacing_ns is None else spacing_ns
    if spacing_ns + taken_ns >= horizon_ns:  # the next chunk, taken after this one's observation
        raise StartupRefused(f"start-up: inference latency {latency_ns * 1e-6:.0f} ms plus one servo period "
                             f"{period_ns * 1e-6:.0f} ms (a chunk is taken at the next tick) does not fit the chunk: "
                             f"the next one, asked for {spacing_ns * 1e-6:.0f} ms after this one's observation (one "
                             f"request at a time), would arrive {(spacing_ns + taken_ns) * 1e-6:.0f} ms after it, "
                             f"past its horizon {horizon_ns * 1e-6:.0f} ms: the robot would run out of steps; "
                             f"not moving")
    gap_ns = spacing_ns + period_ns  # from one chunk taken to the next, taken up to one period late
    why = None if watchdog_ns is None else watchdog_refusal(
        watchdog_ns * 1e-9, gap_ns, f"up to {gap_ns * 1e-6:.0f} ms (the next asked for {spacing_ns * 1e-6:.0f} ms "
                                    "after this one's observation, taken up to one servo period late)")
    if why is not None:
        raise StartupRefused(f"start-up: {why}")


def watchdog_refusal(watchdog_s: float, gap_ns: int, gap: str) -> str | None:
    """Why the policy watchdog ``watchdog_s`` [s] would stop the robot at every chunk: it is no longer than
    ``gap_ns``, the time between chunks (``gap``: that time and what makes it up, as the line says it); None where
    it is longer."""
    if round(watchdog_s * 1e9) > gap_ns:
        return None
    return (f"guard.watchdog_s {duration(watchdog_s)} is not longer than the time between chunks, {gap}: the "
            f"watchdog would stop the robot at every chunk; set guard.watchdog_s above {gap_ns * 1e-6:.0f} ms; "
            "not moving")


def duration(seconds: float) -> str:
    """``seconds`` as it reads: whole ms from 1 ms, whole µs below, the value in s under 1 µs (a watchdog of 1e-25 s,
    taken by the scenario, read "0 ms")."""
    if seconds >= 1e-3:
        return f"{seconds * 1e3:.0f} ms"
    return f"{seconds * 1e6:.0f} µs" if seconds >= 1e-6 else f"{seconds:g} s"


@dataclass(frozen=True)
class BoxStart:
    """A tool point that starts outside the workspace ``box``: ``tip`` [m], ``excess`` [m] past its ``wall`` (its
    worst), and the box ``grown`` wall by wall to hold it (``grown_box``), where its first target may lie."""

    box: tuple
    tip: tuple
    excess: float
    wall: str
    grown: tuple

    @classmethod
    def of(cls, box, tip) -> BoxStart | None:
        """The start at tool point ``tip`` [m], or None where it lies inside ``box``."""
        lo, hi = box
        grown = grown_box(tip, lo, hi)
        return None if grown is None else cls(box, tuple(map(float, tip)), *box_excess(tip, lo, hi), grown)

    def __str__(self) -> str:
        """The start, as a refusal and the policy-lost line name it."""
        corners = [list(map(float, corner)) for corner in self.box]
        return (f"the tool point starts {mm(self.excess)} mm outside the workspace box {corners} past its "
                f"{self.wall} (at {at(self.tip, *self.box)} m)")

    def further(self, target) -> str | None:
        """Why a first target at tool point ``target`` [m] is refused (past a wall the tool is inside of, or further
        past one than the tool is, ``SLACK`` allowed), or None where it is taken: the approach goes there. Said
        after the start (``refused``)."""
        beyond, wall = box_excess(target, *self.grown)
        if beyond <= 0.0:
            return None
        axis, (lo, hi) = "xyz".index(wall[0]), self.box
        past = lo[axis] - target[axis] if wall.endswith("min") else target[axis] - hi[axis]
        inside = lo[axis] <= self.tip[axis] <= hi[axis]
        how = f"{mm(past)} mm past its {wall}, a wall the tool is inside of" if inside else \
            f"further out, {mm(past)} mm past its {wall}"
        return f"the first target lies {how} (at {at(target, lo, hi)} m)"

    def refused(self, what: str) -> str:
        """A first chunk refused for ``what`` (``further``'s, or its approach's way further out), after the start."""
        return f"first target: {self} and {what}; nothing approached"


def _checked_stats(name: str, pair, value: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The policy's (q01, q99) for ``name`` as 1-D arrays: numbers, finite, q01 <= q99, one per observed value.
    Bad statistics passed silently (NaN compares false) or ended in a traceback."""
    what = f"start-up: the policy's normalisation statistics for {name}"
    try:
        q01, q99 = (np.asarray(side, dtype=np.float64).ravel() for side in pair)
    except (TypeError, ValueError):
        raise StartupRefused(f"{what}: expected a pair (q01, q99) of number arrays; not moving") from None
    expected, of = value.size, f"the observation {name}"
    for label, side in (("q01", q01), ("q99", q99)):
        if side.size != expected:
            raise StartupRefused(f"{what}: {label} has {side.size} values, {of} has {expected}; not moving")
        bad = np.flatnonzero(~np.isfinite(side))
        if bad.size:
            i = int(bad[0])
            raise StartupRefused(f"{what}: {label}[{i}] = {side[i]} is not finite; not moving")
    inverted = np.flatnonzero(q01 > q99)
    if inverted.size:
        i = int(inverted[0])
        raise StartupRefused(f"{what}: q01[{i}] = {q01[i]:.4g} is above q99[{i}] = {q99[i]:.4g}; not moving")
    return q01, q99


def _observed(observation, name: str) -> np.ndarray | None:
    if name in ("q", "state", "observation.state"):
        return np.asarray(observation.q, dtype=np.float64)
    value = observation.measurements.get(name)
    return None if value is None else np.asarray(value, dtype=np.float64).ravel()
