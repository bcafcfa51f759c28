"""A joint's friction changed at once (a seal replaced, debris in a gearbox): x ``factor`` from a cycle on."""

from typing import Literal

from pydantic import Field

from cellguard.robot.faults.base import Fault


class FrictionStep(Fault):
    kind: Literal["friction_step"]
    joint: str
    at_cycle: int = Field(default=0, ge=0)
    factor: float = Field(gt=0, le=20.0, description="friction as a multiple of the nominal")

    def apply(self, cell, cycle: int) -> None:
        cell.set_friction_scale(self.joint, self.factor if cycle >= self.at_cycle else 1.0)

    def joints(self) -> list[str]:
        return [self.joint]
