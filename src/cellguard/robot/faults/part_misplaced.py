"""Parts presented out of place now and then (a feeder that mis-seats one part in five): the part
sits off its fixture datum on some cycles; the camera sees it truly."""

from typing import Literal

import numpy as np
from pydantic import Field

from cellguard.robot.faults.base import Fault
from cellguard.robot.faults.intermittent import hits


class PartMisplaced(Fault):
    kind: Literal["part_misplaced"]
    at_cycle: int = Field(default=0, ge=0)
    rate: float = Field(gt=0, le=1.0, description="share of cycles it happens in")
    seed: int = Field(default=0, ge=0)
    dx_mm: float = Field(default=2.0, ge=-30, le=30)
    dy_mm: float = Field(default=0.0, ge=-30, le=30)

    def apply(self, cell, cycle: int) -> None:
        on = hits(cycle, self.at_cycle, self.rate, self.seed)
        cell.set_part_offset(np.array([self.dx_mm, self.dy_mm, 0.0]) * 1e-3 * on)
