"""Retry the grasp with a search offset: each attempt shifts the pick along the next direction of a fixed
pattern (+x, -x, +y, -y) around where the gripper closed, then finishes the cycle. Each lap of the pattern
goes one ``search_mm`` further out (attempts 1-4 at ``search_mm``, 5-8 at twice it, ...): a fifth attempt
at the first one's pose would only repeat a grasp that already missed. An offset the arm cannot reach ends
the recoveries (the runner gives up on a plan it cannot make).

For a gripper or tool that sits off where the kinematics say (a slip): the cell cannot measure the
slip, so it searches.
"""

from typing import Literal

import numpy as np
from pydantic import Field

from cellguard.robot.recovery.base import Plan, Recovery, pick_and_finish

PATTERN = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0]])


class RetryGrasp(Recovery):
    do: Literal["retry_grasp"]
    needs = ("reach", "tool_taught", "drop_point")
    search_mm: float = Field(default=4.0, gt=0.0, le=20.0, description="search step of each attempt, and how "
                             "much further out each lap of the pattern goes [mm]")

    def plan(self, cell, q: np.ndarray, attempt: int, origin: np.ndarray) -> Plan:
        lap, direction = divmod(attempt - 1, len(PATTERN))
        offset = PATTERN[direction] * self.search_mm * (lap + 1) * 1e-3
        return pick_and_finish(cell, q, cell.tool_taught(origin[:-1]) + offset, self.speed_scale)
