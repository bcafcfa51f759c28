"""Drift monitors: CUSUMs per feature, pooled CUSUMs per joint, and a multivariate EWMA.

- Per feature, a two-sided CUSUM with ``k = 1``: tuned to shifts of two baseline scales and blind
  to the error of a median taken from twenty acceptance cycles (about 0.3 scale).
- Per joint, two pooled channels: the mean of its current features (with its friction torque)
  and the mean of its tracking-error features, each standardised by its spread under the baseline correlation, with
  a smaller ``k = 0.5``. One physical cause moves these together (a weaker servo raises the
  tracking error over the whole motion of that joint, friction its current), so a change too
  small for any one feature adds up in the pooled channel.
- A multivariate EWMA (T^2 with a shrunk correlation) over all features.

Thresholds are set for the whole set: a third of the false-alarm budget to each bank. Each of
the ``m`` one-sided CUSUMs of a bank gets an in-control run length of ``3 m`` times the target
for the set (Siegmund's approximation for unit-variance residuals), so adding features does not
add false alarms.

Residuals are clipped before they enter a CUSUM so that one odd cycle (a single bad grasp, a
sensor spike) cannot raise a drift alarm by itself; a change that persists alarms on its
second cycle. One-off incidents are the events' business (and the intermittent monitor's), not drift's.

A monitor that alarmed re-arms once its change has ended (``REARM`` cycles in a row back under its
reference value), its sum restarted: a change after an episode that ended is an alarm of its own
(a latency on four cycles had spent the alarm of the servo loss that came three cycles after it).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from cellguard.diagnose.baseline import Baseline
from cellguard.diagnose.cycles import Cycle
from cellguard.diagnose.feature_kinds import kind_of, member_of

SIEGMUND_OFFSET = 1.166
REARM = 3  # [cycles] in a row back under the reference value (the T^2 limit): the change that alarmed has ended


@dataclass(frozen=True)
class DriftConfig:
    """Detector settings; ``set_arl`` is the mean number of fault-free cycles between false
    alarms of the whole set (all features, both directions, and the multivariate check)."""

    k: float = 1.0
    set_arl: float = 100_000.0
    ewma_lambda: float = 0.2
    ewma_clip: float = 4.0
    pooled_k: float = 0.5
    banks: int = 3  # the budget is split evenly: per-feature CUSUMs, pooled CUSUMs, multivariate EWMA

    def cusum_threshold(self, features: int, k: float | None = None) -> float:
        """``h`` such that each of the ``2 * features`` one-sided CUSUMs of a bank (reference value
        ``k``, default ``self.k``) has ARL0 = 2 p x banks x set_arl: the bank's share of the budget."""
        return siegmund_threshold(2.0 * max(features, 1) * self.banks * self.set_arl, self.k if k is None else k)

    def clip(self, h: float, k: float | None = None) -> float:
        """Largest residual one cycle may add: half the threshold, so two cycles are needed."""
        return 0.5 * h + (self.k if k is None else k) + 0.25

    def mewma_threshold(self, features: int) -> float:
        """Chi-square quantile (Wilson-Hilferty) at a per-cycle rate of 1 / (banks x set_arl)."""
        z = NormalDist().inv_cdf(1.0 - 1.0 / (self.banks * self.set_arl))
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
    pooled_k: float = 0.5  # of the pooled channels, named in their alarms (``tracking_pooled.<joint>`` ...)
    pooled_threshold: float = float("nan")

    def series(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """(upper, lower) CUSUM of one feature."""
        j = self.names.index(name)
        return self.upper[:, j], self.lower[:, j]


def detect_drift(baseline: Baseline, cycles: Sequence[Cycle], config: DriftConfig = DriftConfig(),
                 residuals: np.ndarray | None = None) -> DriftResult:
    """Run the monitors over ``cycles`` (those after the baseline) in order; ``residuals`` replaces
    ``baseline.residuals(cycles)`` when the caller has conditioned them (declared process changes)."""
    z = baseline.residuals(cycles) if residuals is None else residuals
    n, p = z.shape
    index = [c.index for c in cycles]
    h = config.cusum_threshold(p)
    zc = np.clip(z, -config.clip(h), config.clip(h))
    names, pooled = pooled_channels(baseline, zc)
    hp = config.cusum_threshold(len(names), config.pooled_k)
    clip = config.clip(hp, config.pooled_k)
    q = len(names)  # both banks in one pass: columns [features | pooled channels]
    upper, lower, alarms = _cusums(np.hstack([zc, np.clip(pooled, -clip, clip)]),
                                   np.r_[np.full(p, config.k), np.full(q, config.pooled_k)],
                                   np.r_[np.full(p, h), np.full(q, hp)], baseline.names + names, index)
    upper, lower = upper[:, :p], lower[:, :p]
    mewma, limit, mv_alarms = _mewma(baseline, z, index, config)
    alarms += mv_alarms
    alarms.sort(key=lambda a: (a.cycle, a.onset, a.signal))
    return DriftResult(baseline.names, tuple(index), config.k, z, upper, lower, h, mewma, limit, tuple(alarms),
                       config.set_arl, config.pooled_k, hp)


def pooled_channels(baseline: Baseline, zc: np.ndarray) -> tuple[tuple[str, ...], np.ndarray]:
    """Per joint, the mean of its current and of its tracking-error residuals, each over its standard
    deviation under the baseline correlation; Shape (cycles, channels). NaN where a member is NaN."""
    groups: dict[str, list[int]] = {}
    for j, name in enumerate(baseline.names):
        kind = kind_of(name)
        if kind.family == "joint" and kind.per == "joint":
            quantity = "tracking" if kind.stem.startswith("tracking") else "current"
            groups.setdefault(f"{quantity}_pooled.{member_of(name)}", []).append(j)
    groups = {k: v for k, v in groups.items() if len(v) > 1}
    if not groups:
        return (), np.zeros((len(zc), 0))
    corr = baseline.correlation()
    out = np.empty((len(zc), len(groups)))
    for c, cols in enumerate(groups.values()):
        w = np.full(len(cols), 1.0 / len(cols))
        sd = float(np.sqrt(w @ corr[np.ix_(cols, cols)] @ w))
        out[:, c] = zc[:, cols] @ w / sd  # NaN propagates: a cycle at another load is skipped
    return tuple(groups), out


def _cusums(zc: np.ndarray, k: np.ndarray, h: np.ndarray, names: Sequence[str], index: list[int]):
    """Two-sided CUSUMs of the columns of ``zc`` with per-column reference value ``k`` and threshold ``h``
    (NaN: no reading, the sum holds); an alarm per side and episode: a side that alarmed re-arms, its sum
    restarted, after ``REARM`` readings in a row under ``k`` on its side."""
    n, p = zc.shape
    upper, lower = np.zeros((n, p)), np.zeros((n, p))
    sums, starts = [np.zeros(p), np.zeros(p)], [np.zeros(p, dtype=int), np.zeros(p, dtype=int)]
    fired, back = [np.zeros(p, dtype=bool), np.zeros(p, dtype=bool)], [np.zeros(p, dtype=int), np.zeros(p, dtype=int)]
    alarms: list[DriftAlarm] = []
    for i in range(n):
        seen = ~np.isnan(zc[i])
        r = np.where(seen, zc[i], 0.0)
        for side, sign in ((0, 1.0), (1, -1.0)):
            s, step = sums[side], sign * r - k
            back[side] = np.where(seen, np.where(step <= 0.0, back[side] + 1, 0), back[side])
            rearm = fired[side] & (back[side] >= REARM)
            s = np.where(rearm, 0.0, s)
            fired[side] &= ~rearm
            new = np.where(seen, np.maximum(0.0, s + step), s)
            starts[side] = np.where((s == 0) & (new > 0), i, starts[side])
            sums[side] = new
            for j in np.flatnonzero((new > h) & ~fired[side]):
                alarms.append(DriftAlarm(names[j], index[i], float(new[j]), index[starts[side][j]], int(sign)))
            fired[side] |= new > h
        upper[i], lower[i] = sums
    return upper, lower, alarms


def _mewma(baseline: Baseline, z: np.ndarray, index: list[int], config: DriftConfig):
    """Multivariate EWMA of the clipped residuals with a shrunk correlation; an alarm per episode (re-armed
    after ``REARM`` cycles in a row under its limit)."""
    inv = np.linalg.inv(baseline.correlation())
    lam = config.ewma_lambda
    limit = config.mewma_threshold(z.shape[1])
    e = np.zeros(z.shape[1])
    out = np.zeros(len(z))
    alarms, armed, under = [], True, 0
    for i, row in enumerate(np.clip(z, -config.ewma_clip, config.ewma_clip)):
        r = np.where(np.isnan(row), 0.0, row)
        e = lam * r + (1.0 - lam) * e
        out[i] = float(e @ inv @ e) * (2.0 - lam) / lam
        under = under + 1 if out[i] <= limit else 0
        armed = armed or under >= REARM
        if armed and out[i] > limit:
            alarms.append(DriftAlarm("multivariate", index[i], float(out[i]), index[i], 0))
            armed = False
    return out, limit, alarms


def siegmund_threshold(arl: float, k: float) -> float:
    """``h`` of a one-sided CUSUM with reference value ``k`` whose in-control ARL is ``arl``."""
    lo, hi = 0.1, 200.0
    for _ in range(60):
        h = 0.5 * (lo + hi)
        lo, hi = (h, hi) if _siegmund_arl(h, k) < arl else (lo, h)
    return hi


def _siegmund_arl(h: float, k: float) -> float:
    """In-control average run length of a one-sided CUSUM on N(0, 1) residuals."""
    b = 2.0 * k * (h + SIEGMUND_OFFSET)
    return (math.exp(b) - b - 1.0) / (2.0 * k * k)
