"""Whether the acceptance cycles were steady: a baseline taken while a fault was already under way
(friction growing from the first cycle) holds part of it, so the change it reads later is too small
and dated to the first production cycle, however early it began.

Per feature, Kendall's rank correlation of its readings with their order (exact for few cycles),
at a level shared by all the features together (``LEVEL``, Bonferroni), and a fitted change over the
acceptance (Theil-Sen slope times its span) of at least ``MATERIAL`` of the feature's scale floor:
a trend far under the smallest change that matters says nothing about the cell. Five cycles cannot
show one at this level (their smallest p is 1/60).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.stats import kendalltau, theilslopes

from cellguard.diagnose.feature_kinds import scale_floor

LEVEL = 0.01  # chance that a steady acceptance reads as trending, all features together
MATERIAL = 2.0  # [scale floors] a smaller change over the acceptance is not a trend worth naming


def trends(names: Sequence[str], x: np.ndarray) -> dict[str, float]:
    """Features of ``x`` (Shape (cycles, names), in cycle order) that trend over the cycles, with the
    fitted change from the first cycle to the last [their unit]."""
    found = {}
    order = np.arange(len(x), dtype=float)
    for j, name in enumerate(names):
        col = x[:, j]
        seen = ~np.isnan(col)
        if seen.sum() < 3 or np.ptp(col[seen]) == 0.0:
            continue
        tau, p = kendalltau(order[seen], col[seen])
        if not p < LEVEL / len(names):
            continue
        change = float(theilslopes(col[seen], order[seen])[0] * np.ptp(order[seen]))
        if abs(change) >= MATERIAL * scale_floor(name, float(np.median(col[seen]))):
            found[name] = change
    return found
