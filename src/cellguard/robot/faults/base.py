"""A fault injected into a simulated cell or its policy channel; one kind per module.

A fault is a validated value (pydantic, unknown keys refused) with three hooks the runner
calls; each kind overrides the one it needs. World faults set absolute values from the cell's
nominal ones, so applying a fault again at the next cycle is harmless.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class Fault(BaseModel):
    """Base of every fault kind; ``kind`` is the discriminator in scenario files."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    def apply(self, cell, cycle: int) -> None:
        """Change the simulated world for ``cycle`` (called at the start of every cycle)."""

    def extra_latency_s(self, cycle: int) -> float:
        """Added inference latency during ``cycle`` [s]."""
        return 0.0

    def corrupts_output(self, cycle: int) -> bool:
        """Whether the policy's output is corrupted (NaN) once during ``cycle``."""
        return False

    def recovery_speed(self, cycle: int) -> float:
        """Share of its planned speed a recovery's arm motion runs at during ``cycle``."""
        return 1.0

    def joints(self) -> list[str]:
        """Joints this fault names, checked against the cell's profile before anything runs."""
        return []
