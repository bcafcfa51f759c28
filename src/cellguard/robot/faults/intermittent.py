"""Which cycles an intermittent fault hits: each cycle from ``at_cycle`` on with probability ``rate``.

Drawn from (``seed``, cycle) alone, so a cycle is hit or not whatever ran before it, and a
scenario replays the same hits.
"""

import numpy as np


def hits(cycle: int, at_cycle: int, rate: float, seed: int) -> bool:
    """Whether an intermittent fault is present in ``cycle``."""
    return cycle >= at_cycle and float(np.random.default_rng([seed, cycle]).random()) < rate
