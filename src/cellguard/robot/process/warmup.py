"""A restart after idle: cold joints have higher friction for the first cycles, decaying.

Friction of every joint = commissioned x (1 + ``friction`` x exp(-(cycle - at_cycle) / ``cycles``))
from ``at_cycle`` on (lubricant viscosity falls as the drives warm up).
"""

import math
from collections.abc import Mapping
from typing import ClassVar, Literal

from pydantic import Field

from cellguard.robot.process.base import ProcessChange


class Warmup(ProcessChange):
    kind: Literal["warmup"]
    idle_min: float = Field(default=120.0, gt=0, le=100_000, description="idle time before the restart [min]")
    friction: float = Field(default=0.5, ge=0, le=5.0, description="extra friction at the restart, x nominal")
    cycles: float = Field(default=4.0, gt=0, le=1000, description="decay constant [cycles]")
    hook: ClassVar[str] = "set_friction_scale"
    diagnosis: ClassVar[str] = "settle"

    @classmethod
    def describe(cls, declared: Mapping) -> str:
        idle = declared.get("idle_min")
        return "restart" + (f" after {idle:g} min idle" if isinstance(idle, (int, float)) else "")

    def apply(self, cell, cycle: int) -> None:
        if cycle >= self.at_cycle:
            factor = 1.0 + self.friction * math.exp(-(cycle - self.at_cycle) / self.cycles)
            for joint in cell.profile.joint_names:
                cell.set_friction_scale(joint, factor)
