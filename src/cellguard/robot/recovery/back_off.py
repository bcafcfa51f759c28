"""Back off and re-approach slower: open, lift, come down again on the same pick at ``speed_scale``
(half the taught speed by default), then finish the cycle. For a grasp lost to the motion itself
(a lagging joint, a part nudged on the way in), not to a pose that is wrong.
"""

from typing import Literal

import numpy as np
from pydantic import Field

from cellguard.robot.recovery.base import Plan, Recovery, pick_and_finish


class BackOff(Recovery):
    do: Literal["back_off"]
    needs = ("reach", "tool_taught", "drop_point")
    speed_scale: float = Field(default=0.5, gt=0.05, le=1.0, description="share of the taught speed")

    def plan(self, cell, q: np.ndarray, attempt: int, origin: np.ndarray) -> Plan:
        return pick_and_finish(cell, q, cell.tool_taught(origin[:-1]), self.speed_scale)
