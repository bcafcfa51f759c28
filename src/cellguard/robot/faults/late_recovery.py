"""A recovery that arrives late at contact: from ``at_cycle`` on, a speed override scales the arm's axes
during recoveries to ``speed_scale`` while the gripper keeps the recovery's own timing, so the fingers
shut before the tool has come down (an override meant for the arm alone, a gripper on a timer)."""

from typing import Literal

from pydantic import Field

from cellguard.robot.faults.base import Fault


class LateRecovery(Fault):
    kind: Literal["late_recovery"]
    at_cycle: int = Field(default=0, ge=0)
    speed_scale: float = Field(default=0.5, gt=0.05, lt=1.0, description="share of the planned arm speed")

    def recovery_speed(self, cycle: int) -> float:
        return self.speed_scale if cycle >= self.at_cycle else 1.0
