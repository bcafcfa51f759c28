"""The camera was knocked: it still reports truly in its own frame, but its calibration is stale."""

from typing import Literal

import numpy as np
from pydantic import Field

from cellguard.robot.faults.base import Fault


class CameraShift(Fault):
    kind: Literal["camera_shift"]
    at_cycle: int = Field(ge=0)
    dx_mm: float = Field(ge=-50, le=50)
    dy_mm: float = Field(default=0.0, ge=-50, le=50)

    def apply(self, cell, cycle: int) -> None:
        on = cycle >= self.at_cycle
        cell.set_camera_offset(np.array([self.dx_mm, self.dy_mm, 0.0]) * 1e-3 * on)
