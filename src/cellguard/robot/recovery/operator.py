"""Hand over to an operator: a category 2 stop with power kept for ``hold_s`` (the operator clears
the cell), an operator reset event, then home. The last resort of an escalation; the cycle fails.
"""

from typing import Literal

import numpy as np
from pydantic import Field

from cellguard.robot.recovery.base import Plan, Recovery, go_home


class Operator(Recovery):
    do: Literal["operator"]
    needs = ("reach", "tool_taught")
    hold_s: float = Field(default=5.0, gt=0.0, le=3600.0, description="time the operator takes [s]")

    def plan(self, cell, q: np.ndarray, attempt: int, origin: np.ndarray) -> Plan:
        return go_home(cell, q, self.speed_scale, hold_s=self.hold_s)
