"""The tool slipped on the flange: the tool point is no longer where the kinematics say."""

from typing import Literal

import numpy as np
from pydantic import Field

from cellguard.robot.faults.base import Fault


class ToolSlip(Fault):
    kind: Literal["tool_slip"]
    at_cycle: int = Field(ge=0)
    dx_mm: float = Field(default=3.0, ge=-30, le=30)
    dy_mm: float = Field(default=0.0, ge=-30, le=30)
    dz_mm: float = Field(default=0.0, ge=-30, le=30)

    def apply(self, cell, cycle: int) -> None:
        on = cycle >= self.at_cycle
        cell.set_tool_offset(np.array([self.dx_mm, self.dy_mm, self.dz_mm]) * 1e-3 * on)
