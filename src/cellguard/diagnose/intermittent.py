"""Intermittent faults: a change present on some cycles only (a part presented out of place one
cycle in five, a gripper that slips now and then).

A CUSUM is the wrong tool: each odd cycle is clipped, and between them the sum decays, so the
fault is averaged away or, at a high rate, read as a step. Here a cycle is an outlier of a
feature when its residual exceeds ``OUTLIER`` scales (beyond the CUSUM's clip, so far in the
tail that fault-free cycles do not reach it); a family of features with outliers on at least
``MIN_HITS`` cycles, but not on nearly every cycle since the first (that is a step, drift's
business), is intermittent. A feature counts only if it is back at its baseline between the hits
(median residual within ``BETWEEN`` scales): a feature that stepped and whose noisy tail crosses
the outlier line now and then (the place error after a fixture shift) is a step, not intermittent. Its rate is the share of cycles hit from the first occurrence on.
The outlier cycles are taken out of the drift monitors so that the same fault is not also
reported as a step.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from cellguard.diagnose.cycles import Cycle
from cellguard.diagnose.feature_kinds import kind_of

OUTLIER = 6.0  # [scales]
MIN_HITS = 3  # outlier cycles before a pattern counts
MAX_RATE = 0.7  # hit on more cycles than this since the first: a step, not intermittent
BETWEEN = 2.0  # [scales] |median residual| on the cycles between hits above this: the feature stepped
FAMILIES = ("geometry", "outcome")  # what one bad cycle shows in; joint and latency changes are drift's


@dataclass(frozen=True)
class Intermittent:
    """Cycles on which ``family`` features were outliers; ``rate`` over the cycles from the first on."""

    family: str
    cycles: tuple[int, ...]
    rate: float
    signals: tuple[str, ...]

    @property
    def first(self) -> int:
        return self.cycles[0]


def find_intermittent(names: Sequence[str], cycles: Sequence[Cycle], z: np.ndarray) -> list[Intermittent]:
    """Intermittent patterns in ``z`` (Shape (cycles, features)), one per family at most."""
    index = np.array([c.index for c in cycles])
    out = []
    for fam in FAMILIES:
        cols = [j for j, n in enumerate(names) if kind_of(n).family == fam]
        if not cols:
            continue
        with np.errstate(invalid="ignore"):
            hit = np.abs(np.nan_to_num(z[:, cols])) > OUTLIER
        keep = [i for i, c in enumerate(cols) if hit[:, i].any() and _back_between(z[:, c], hit[:, i])]
        hit, cols = hit[:, keep], [cols[i] for i in keep]
        rows = np.flatnonzero(hit.any(axis=1))
        if len(rows) < MIN_HITS:
            continue
        rate = len(rows) / (len(index) - rows[0])
        if rate > MAX_RATE:
            continue
        signals = tuple(sorted(names[c] for c in cols))
        out.append(Intermittent(fam, tuple(int(i) for i in index[rows]), float(rate), signals))
    return out


def _back_between(col: np.ndarray, hit: np.ndarray) -> bool:
    """Whether a feature with outliers ``hit`` (Shape (cycles,)) sits at its baseline on the cycles
    between them, from the first hit on (no such cycle read: yes)."""
    first = int(np.argmax(hit))
    between = col[first:][~hit[first:]]
    between = between[~np.isnan(between)]
    return not len(between) or abs(float(np.median(between))) <= BETWEEN


def without_outliers(names: Sequence[str], cycles: Sequence[Cycle], z: np.ndarray,
                     found: Sequence[Intermittent]) -> np.ndarray:
    """``z`` with the intermittent cycles of each found family set to NaN (not read by drift)."""
    if not found:
        return z
    z = z.copy()
    index = [c.index for c in cycles]
    for f in found:
        rows = [index.index(i) for i in f.cycles]
        cols = [j for j, n in enumerate(names) if kind_of(n).family == f.family]
        z[np.ix_(rows, cols)] = np.nan
    return z
