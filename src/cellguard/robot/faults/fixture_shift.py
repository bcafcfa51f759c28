"""The fixture moved on the table: the part now sits elsewhere; the camera sees it truly."""

from typing import Literal

import numpy as np
from pydantic import Field

from cellguard.robot.faults.base import Fault


class FixtureShift(Fault):
    kind: Literal["fixture_shift"]
    at_cycle: int = Field(ge=0)
    dx_mm: float = Field(ge=-50, le=50)
    dy_mm: float = Field(default=0.0, ge=-50, le=50)

    def apply(self, cell, cycle: int) -> None:
        on = cycle >= self.at_cycle
        cell.set_fixture_offset(np.array([self.dx_mm, self.dy_mm, 0.0]) * 1e-3 * on)
