"""Whether the acceptance cycles were steady: a baseline taken while a fault was already under way
(friction growing from the first cycle) holds part of it, so the change it reads later is too small
and dated to the first production cycle, however early it began.

Per feature, Kendall's rank correlation of its readings with their order (exact for few cycles),
at a level shared by all the features together (``LEVEL``, Bonferroni), and a fitted change over the
acceptance (Theil-Sen slope times its span) of at least ``MATERIAL`` of the feature's scale floor:
a trend far under the smallest change that matters says nothing about the cell. Five cycles cannot
show one at this level (their smallest p is 1/60).

Beside it, a step: the best least-squares split of the readings into two levels (at least ``SIDE``
cycles each), its t statistic against the spread within the levels, at the same shared level
(Bonferroni over the splits too). A rank test cannot see a step in few cycles: ten cycles whose
elbow error stepped 3 % (40 noise sigmas) half way read p = 0.004 at best, against 0.01 shared by 70
features. The step is named where it is ``MATERIAL`` too, its change the difference of the levels, with the
cycle its second level began (a technician looks there: a step is an event, a trend a wear).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from scipy.stats import kendalltau, t as student, theilslopes

from cellguard.diagnose.feature_kinds import scale_floor

LEVEL = 0.01  # chance that a steady acceptance reads as trending, all features together
MATERIAL = 2.0  # [scale floors] a smaller change over the acceptance is not a trend worth naming
SIDE = 3  # [cycles] the fewest on either side of a step: two cycles that share an odd condition are no level


class Unsteady(NamedTuple):
    """How a feature moved over the acceptance: its change [its unit] and, for a step, the row of the cycles where
    the second level began (None for a trend)."""

    change: float
    step_at: int | None = None


def trends(names: Sequence[str], x: np.ndarray) -> dict[str, Unsteady]:
    """Features of ``x`` (Shape (cycles, names), in cycle order) that trend, or step, over the cycles, with the
    fitted change from the first cycle to the last [their unit] and where a step began (a row of ``x``)."""
    found = {}
    order = np.arange(len(x), dtype=float)
    level = LEVEL / max(len(names), 1)
    for j, name in enumerate(names):
        col = x[:, j]
        seen = ~np.isnan(col)
        if seen.sum() < 3 or np.ptp(col[seen]) == 0.0:
            continue
        floor = MATERIAL * scale_floor(name, float(np.median(col[seen])))
        tau, p = kendalltau(order[seen], col[seen])
        line = theilslopes(col[seen], order[seen]) if p < level else None
        change = 0.0 if line is None else float(line[0] * np.ptp(order[seen]))
        step, k, levels = _step(col[seen], level)
        if max(abs(step), abs(change)) < floor:
            continue
        # told as the model that fits the readings better: a clean step half way reads as a steeper line too
        off = None if line is None else col[seen] - (line[1] + line[0] * order[seen])
        stepped = step != 0.0 and (off is None or levels <= float(np.sum(off * off)))
        found[name] = Unsteady(step, int(np.flatnonzero(seen)[k])) if stepped else Unsteady(change)
    return found


def _step(col: np.ndarray, level: float) -> tuple[float, int, float]:
    """The change of the best least-squares split of ``col`` into two levels where its t statistic is
    significant at ``level`` over all the splits tried (Bonferroni), else 0; where its second level begins; and
    the split's sum of squared residuals."""
    n = len(col)
    splits = range(SIDE, n - SIDE + 1)
    if not len(splits):
        return 0.0, 0, float("inf")
    sse = [(float(np.sum((col[:k] - col[:k].mean()) ** 2) + np.sum((col[k:] - col[k:].mean()) ** 2)), k)
           for k in splits]
    best, k = min(sse)
    change = float(col[k:].mean() - col[:k].mean())
    spread = np.sqrt(best / (n - 2)) * np.sqrt(1.0 / k + 1.0 / (n - k))
    if spread == 0.0:
        return change, k, best
    p = 2.0 * student.sf(abs(change) / spread, n - 2) * len(splits)
    return (change if p < level else 0.0), k, best
