"""Intermittent faults: an offset present on some cycles only, each cycle from ``at_cycle`` on with
probability ``rate``.

Drawn from (``seed``, cycle) alone, so a cycle is hit or not whatever ran before it, and a
scenario replays the same hits.
"""

from typing import ClassVar

import numpy as np
from pydantic import Field

from cellguard.robot.faults.base import Fault


def hits(cycle: int, at_cycle: int, rate: float, seed: int) -> bool:
    """Whether an intermittent fault is present in ``cycle``."""
    return cycle >= at_cycle and float(np.random.default_rng([seed, cycle]).random()) < rate


class IntermittentOffset(Fault):
    """An offset [mm] the cell's ``setter`` applies on the cycles the fault hits, zero on the others."""

    setter: ClassVar[str]
    at_cycle: int = Field(default=0, ge=0)
    rate: float = Field(gt=0, le=1.0, description="share of cycles it happens in")
    seed: int = Field(default=0, ge=0)
    dx_mm: float = Field(default=2.0, ge=-30, le=30)
    dy_mm: float = Field(default=0.0, ge=-30, le=30)

    def apply(self, cell, cycle: int) -> None:
        on = hits(cycle, self.at_cycle, self.rate, self.seed)
        getattr(cell, self.setter)(np.array([self.dx_mm, self.dy_mm, 0.0]) * 1e-3 * on)
