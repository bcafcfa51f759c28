"""The policy emits NaN once (a numerical blow-up, a bad normalisation statistic)."""

from typing import Literal

from pydantic import Field

from cellguard.robot.faults.base import Fault


class PolicyNaN(Fault):
    kind: Literal["policy_nan"]
    at_cycle: int = Field(ge=0)

    def corrupts_output(self, cycle: int) -> bool:
        return cycle == self.at_cycle
