"""A servo's position gain changed (retuned drive, failing amplifier): weaker or stiffer tracking."""

from typing import Literal

from pydantic import Field, field_validator

from cellguard.robot.faults.base import Fault


class ServoGain(Fault):
    kind: Literal["servo_gain"]
    joint: str | list[str]
    factor: float = Field(gt=0.05, le=3.0)
    at_cycle: int = Field(default=0, ge=0)

    @field_validator("joint")
    @classmethod
    def _each_once(cls, joint):
        """A joint listed twice had its gain scaled twice (the factors compose), while the record says once; an
        empty list injected nothing while the ground truth named the fault."""
        if isinstance(joint, list) and not joint:
            raise ValueError("an empty list names no joint")
        if isinstance(joint, list) and len(set(joint)) < len(joint):
            raise ValueError(f"a joint is listed twice: {joint}")
        return joint

    def apply(self, cell, cycle: int) -> None:
        factor = self.factor if cycle >= self.at_cycle else 1.0
        for joint in self.joints():
            cell.set_servo_gain(joint, factor)

    def joints(self) -> list[str]:
        return [self.joint] if isinstance(self.joint, str) else list(self.joint)
