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

An intermittent fault already present at acceptance sits in the baseline: the acceptance median is the faulty
level where it hit most acceptance cycles, and the cycles it spares read off the baseline, toward the clean level
(a drift toward the clean level that a CUSUM reads as a new step). Only a feature whose clean level is known tells
the two apart: the part-to-tool offset at grasp (``AT_ZERO``, part centre minus tool point) reads zero where the
tool holds its place on the flange. Where the watched cycles of the offset are two-valued, those that read the
baseline off zero and those back at zero, interleaved, the fault is intermittent from the start: its cycles are
those at the baseline, and the clean ones are what the drift monitors do not read.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from cellguard.diagnose.baseline import MAD_TO_SIGMA, feature_matrix
from cellguard.diagnose.cycles import Cycle
from cellguard.diagnose.feature_kinds import kind_of, scale_floor

OUTLIER = 6.0  # [scales]
MIN_HITS = 3  # outlier cycles before a pattern counts
MAX_RATE = 0.7  # hit on more cycles than this since the first: a step, not intermittent
BETWEEN = 2.0  # [scales] |median residual| on the cycles between hits above this: the feature stepped
FAMILIES = ("geometry", "outcome")  # what one bad cycle shows in; joint and latency changes are drift's
AT_ZERO = "grasp_offset_"  # features whose clean level is zero: the part-to-tool offset at grasp, per axis
SPARED = 3.0  # [scales] off a baseline that holds the fault, toward zero: a cycle the fault spared


@dataclass(frozen=True)
class Intermittent:
    """Cycles on which ``family`` features were outliers; ``rate`` over the cycles from the first on. For one present
    at acceptance, ``clean`` holds the cycles back at the clean level (off the baseline) and ``rate`` is over all
    the watched cycles."""

    family: str
    cycles: tuple[int, ...]
    rate: float
    signals: tuple[str, ...]
    clean: tuple[int, ...] = ()

    @property
    def first(self) -> int:
        return self.cycles[0]

    @property
    def off_baseline(self) -> tuple[int, ...]:
        """The cycles whose features read off the baseline: the hits, or the clean ones where the baseline holds it."""
        return self.clean or self.cycles


def find_intermittent(names: Sequence[str], cycles: Sequence[Cycle], z: np.ndarray) -> list[Intermittent]:
    """Intermittent patterns in ``z`` (Shape (cycles, features)): one per family at most, and one the baseline holds."""
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
    held = _at_acceptance(names, cycles, z)
    # the cycles a fault the baseline holds spared are outliers against it, not a fault's cycles
    return [f for f in out if not any(set(f.cycles) <= set(h.clean) for h in held)] + held


def _at_acceptance(names: Sequence[str], cycles: Sequence[Cycle], z: np.ndarray) -> list[Intermittent]:
    """The intermittent fault the baseline holds (module docstring): at most one, in geometry. An offset feature
    counts where the cycles that read its baseline (within ``BETWEEN`` scales) sit ``OUTLIER`` within-level sigmas
    or more off zero and others read ``SPARED`` scales or more off it, at zero; each cycle is at the level nearer
    its readings on the features that count."""
    cols = [j for j, n in enumerate(names) if n.startswith(AT_ZERO)]
    x = feature_matrix(cycles, [names[j] for j in cols])
    with np.errstate(invalid="ignore"):
        at_base, away = np.abs(z[:, cols]) <= BETWEEN, np.abs(z[:, cols]) >= SPARED
    counts = []
    for i, j in enumerate(cols):
        level = float(np.median(x[at_base[:, i], i])) if at_base[:, i].any() else 0.0
        zero = x[away[:, i] & (np.abs(x[:, i]) < np.abs(x[:, i] - level)), i]
        sigma = _within(x[at_base[:, i], i] - level, zero - np.median(zero) if len(zero) else zero, name=names[j])
        if len(zero) and abs(level) >= OUTLIER * sigma and abs(float(np.median(zero))) <= BETWEEN * sigma:
            counts.append((i, level))
    if not counts:
        return []
    x, level = x[:, [i for i, _ in counts]], np.array([v for _, v in counts])
    seen = ~np.isnan(x).any(axis=1)
    hit = seen & nearer_level(x, level)
    clean = seen & ~hit
    index = np.array([c.index for c in cycles])
    if not hit.any() or not clean.any() or index[hit][-1] < index[clean][0]:  # all hits before the clean: a step
        return []
    signals = tuple(sorted(names[cols[i]] for i, _ in counts))
    return [Intermittent("geometry", tuple(int(i) for i in index[hit]), float(hit.sum() / seen.sum()), signals,
                         tuple(int(i) for i in index[clean]))]


def nearer_level(x: np.ndarray, level: np.ndarray) -> np.ndarray:
    """Per cycle, whether offsets ``x`` (Shape (cycles, features)) sit nearer ``level`` (Shape (features,) or that of
    ``x``) than zero, their clean level, summed over the features."""
    return np.sum((x - level) ** 2, axis=1) < np.sum(x ** 2, axis=1)


def _within(*residuals: np.ndarray, name: str) -> float:
    """The spread [its unit] of feature ``name``'s readings about their own level (``residuals``, one array per
    level), not under its floor."""
    d = np.concatenate(residuals)
    return max(MAD_TO_SIGMA * float(np.median(np.abs(d))) if len(d) else 0.0, scale_floor(name, 0.0))


def _back_between(col: np.ndarray, hit: np.ndarray) -> bool:
    """Whether a feature with outliers ``hit`` (Shape (cycles,)) sits at its baseline on the cycles
    between them, from the first hit on (no such cycle read: yes)."""
    first = int(np.argmax(hit))
    between = col[first:][~hit[first:]]
    between = between[~np.isnan(between)]
    return not len(between) or abs(float(np.median(between))) <= BETWEEN


def without_outliers(names: Sequence[str], cycles: Sequence[Cycle], z: np.ndarray,
                     found: Sequence[Intermittent]) -> np.ndarray:
    """``z`` with the cycles off the baseline of each found family set to NaN (not read by drift)."""
    if not found:
        return z
    z = z.copy()
    index = [c.index for c in cycles]
    for f in found:
        rows = [index.index(i) for i in f.off_baseline]
        cols = [j for j, n in enumerate(names) if kind_of(n).family == f.family]
        z[np.ix_(rows, cols)] = np.nan
    return z
