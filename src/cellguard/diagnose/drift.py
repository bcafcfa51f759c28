"""Drift monitors: a two-sided CUSUM per feature and a multivariate EWMA over all of them.

Thresholds are set for the whole feature set: with ``p`` features watched in both directions,
each one-sided CUSUM gets an in-control run length of ``4 p`` times the target for the set
(half the false-alarm budget goes to the CUSUMs, half to the multivariate check; Siegmund's
approximation for unit-variance residuals), so adding features does not add false alarms. ``k = 1`` tunes the CUSUM to shifts of two baseline scales and keeps it blind to
the error of a median taken from twenty acceptance cycles (about 0.3 scale).

Residuals are clipped before they enter a CUSUM so that one odd cycle (a single bad grasp, a
sensor spike) cannot raise a drift alarm by itself; a change that persists alarms on its
second cycle. One-off incidents are the events' business, not drift's.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from cellguard.diagnose.baseline import Baseline
from cellguard.diagnose.cycles import Cycle

SIEGMUND_OFFSET = 1.166


@dataclass(frozen=True)
class DriftConfig:
    """Detector settings; ``set_arl`` is the mean number of fault-free cycles between false
    alarms of the whole set (all features, both directions, and the multivariate check)."""

    k: float = 1.0
    set_arl: float = 100_000.0
    ewma_lambda: float = 0.2
    ewma_clip: float = 4.0

    def cusum_threshold(self, features: int) -> float:
        """``h`` such that each of the ``2 * features`` one-sided CUSUMs has ARL0 = 4 p x set_arl
        (the ``2 p`` CUSUMs share half of the set's false-alarm budget)."""
        target = 2.0 * max(features, 1) * self.set_arl * 2.0  # half the budget to the CUSUMs
        lo, hi = 0.1, 100.0
        for _ in range(60):
            h = 0.5 * (lo + hi)
            lo, hi = (h, hi) if _siegmund_arl(h, self.k) < target else (lo, h)
        return hi

    def clip(self, h: float) -> float:
        """Largest residual one cycle may add: half the threshold, so two cycles are needed."""
        return 0.5 * h + self.k + 0.25

    def mewma_threshold(self, features: int) -> float:
        """Chi-square quantile (Wilson-Hilferty) at a per-cycle rate of 1 / (2 set_arl)."""
        z = NormalDist().inv_cdf(1.0 - 1.0 / (2.0 * self.set_arl))
        p = max(features, 1)
        return p * (1.0 - 2.0 / (9.0 * p) + z * math.sqrt(2.0 / (9.0 * p))) ** 3


@dataclass(frozen=True)
class DriftAlarm:
    """A persistent change: ``signal`` crossed its threshold at ``cycle``; it began at ``onset``
    (the CUSUM's change-point estimate). ``statistic`` is the CUSUM (or T^2) value."""

    signal: str
    cycle: int
    statistic: float
    onset: int
    direction: int  # +1 up, -1 down, 0 for the multivariate check

    def to_dict(self) -> dict:
        direction = "up" if self.direction > 0 else "down" if self.direction < 0 else "any"
        return {"signal": self.signal, "cycle": self.cycle, "statistic": round(self.statistic, 2),
                "onset": self.onset, "direction": direction}


@dataclass(frozen=True)
class DriftResult:
    """Alarms, and the series behind them for the charts. Arrays are Shape (cycles, features)."""

    names: tuple[str, ...]
    cycles: tuple[int, ...]
    k: float
    z: np.ndarray
    upper: np.ndarray
    lower: np.ndarray
    threshold: float
    mewma: np.ndarray  # Shape (cycles,)
    mewma_threshold: float
    alarms: tuple[DriftAlarm, ...]
    set_arl: float  # fault-free cycles between false alarms of the whole set, by design

    def series(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """(upper, lower) CUSUM of one feature."""
        j = self.names.index(name)
        return self.upper[:, j], self.lower[:, j]


def detect_drift(baseline: Baseline, cycles: Sequence[Cycle], config: DriftConfig = DriftConfig()) -> DriftResult:
    """Run the monitors over ``cycles`` (those after the baseline) in order."""
    z = baseline.residuals(cycles)
    n, p = z.shape
    h = config.cusum_threshold(p)
    clip = config.clip(h)
    zc = np.clip(z, -clip, clip)
    upper, lower = np.zeros((n, p)), np.zeros((n, p))
    s_up, s_lo = np.zeros(p), np.zeros(p)
    start_up, start_lo = np.zeros(p, dtype=int), np.zeros(p, dtype=int)
    fired_up, fired_lo = np.zeros(p, dtype=bool), np.zeros(p, dtype=bool)
    index = [c.index for c in cycles]
    alarms: list[DriftAlarm] = []
    for i in range(n):
        row = zc[i]
        seen = ~np.isnan(row)
        r = np.where(seen, row, 0.0)
        new_up = np.where(seen, np.maximum(0.0, s_up + r - config.k), s_up)
        new_lo = np.where(seen, np.maximum(0.0, s_lo - r - config.k), s_lo)
        start_up = np.where((s_up == 0) & (new_up > 0), i, start_up)
        start_lo = np.where((s_lo == 0) & (new_lo > 0), i, start_lo)
        s_up, s_lo = new_up, new_lo
        upper[i], lower[i] = s_up, s_lo
        for j in np.flatnonzero((s_up > h) & ~fired_up):
            alarms.append(DriftAlarm(baseline.names[j], index[i], float(s_up[j]), index[start_up[j]], +1))
        for j in np.flatnonzero((s_lo > h) & ~fired_lo):
            alarms.append(DriftAlarm(baseline.names[j], index[i], float(s_lo[j]), index[start_lo[j]], -1))
        fired_up |= s_up > h
        fired_lo |= s_lo > h
    mewma, limit, mv_alarm = _mewma(baseline, z, index, config)
    if mv_alarm is not None:
        alarms.append(mv_alarm)
    alarms.sort(key=lambda a: (a.cycle, a.onset, a.signal))
    return DriftResult(baseline.names, tuple(index), config.k, z, upper, lower, h, mewma, limit, tuple(alarms),
                       config.set_arl)


def _mewma(baseline: Baseline, z: np.ndarray, index: list[int], config: DriftConfig):
    """Multivariate EWMA of the clipped residuals with a shrunk correlation; first alarm only."""
    inv = np.linalg.inv(baseline.correlation())
    lam = config.ewma_lambda
    limit = config.mewma_threshold(z.shape[1])
    e = np.zeros(z.shape[1])
    out = np.zeros(len(z))
    alarm = None
    for i, row in enumerate(np.clip(z, -config.ewma_clip, config.ewma_clip)):
        r = np.where(np.isnan(row), 0.0, row)
        e = lam * r + (1.0 - lam) * e
        out[i] = float(e @ inv @ e) * (2.0 - lam) / lam
        if alarm is None and out[i] > limit:
            alarm = DriftAlarm("multivariate", index[i], float(out[i]), index[i], 0)
    return out, limit, alarm


def _siegmund_arl(h: float, k: float) -> float:
    """In-control average run length of a one-sided CUSUM on N(0, 1) residuals."""
    b = 2.0 * k * (h + SIEGMUND_OFFSET)
    return (math.exp(b) - b - 1.0) / (2.0 * k * k)
