"""Re-home: open the gripper and go back to the home pose; the cycle ends failed, the next one
starts clean. The fallback for a failure no other behaviour can undo (a part placed off the zone).
"""

from typing import Literal

import numpy as np

from cellguard.robot.recovery.base import Plan, Recovery, go_home


class Rehome(Recovery):
    do: Literal["rehome"]
    needs = ("reach", "tool_taught")

    def plan(self, cell, q: np.ndarray, attempt: int, origin: np.ndarray) -> Plan:
        return go_home(cell, q, self.speed_scale)
