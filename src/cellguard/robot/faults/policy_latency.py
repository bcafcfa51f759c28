"""Inference got slow (a loaded GPU, a network hop): chunks answer older observations."""

from typing import Literal

from pydantic import Field, model_validator

from cellguard.robot.faults.base import Fault


class PolicyLatency(Fault):
    kind: Literal["policy_latency"]
    at_cycle: int = Field(ge=0)
    ms: float = Field(gt=0, le=5000)
    until_cycle: int | None = Field(default=None, ge=0)

    @model_validator(mode="after")
    def _ordered(self):
        if self.until_cycle is not None and self.until_cycle < self.at_cycle:
            raise ValueError(f"until_cycle {self.until_cycle} is before at_cycle {self.at_cycle}")
        return self

    def extra_latency_s(self, cycle: int) -> float:
        active = cycle >= self.at_cycle and (self.until_cycle is None or cycle <= self.until_cycle)
        return self.ms * 1e-3 if active else 0.0
