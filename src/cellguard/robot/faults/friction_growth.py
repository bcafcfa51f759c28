"""A joint's friction grows cycle by cycle (wear, a failing bearing, lost lubrication)."""

from typing import Literal

from pydantic import Field

from cellguard.robot.faults.base import Fault


class FrictionGrowth(Fault):
    kind: Literal["friction_growth"]
    joint: str
    from_cycle: int = Field(ge=0)
    per_cycle: float = Field(gt=0, le=1.0, description="growth per cycle, as a fraction of the nominal friction")

    def apply(self, cell, cycle: int) -> None:
        grown = max(0, cycle - self.from_cycle + 1)
        cell.set_friction_scale(self.joint, 1.0 + self.per_cycle * grown)

    def joints(self) -> list[str]:
        return [self.joint]
