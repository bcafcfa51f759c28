"""The two calls a robot offers cellguard, and the extra calls a simulated cell offers the runner."""

from __future__ import annotations

from typing import Protocol

import numpy as np

from cellguard.embodiment import Profile
from cellguard.robot.state import Observation, State


class Robot(Protocol):
    """A robot at servo rate: MuJoCo cells here; a hardware bridge implements the same calls."""

    profile: Profile

    def read(self) -> State:
        """The measured state now."""

    def write(self, setpoint: np.ndarray) -> np.ndarray:
        """Command joint positions (dof,); return what was actually sent after the drive's own clipping."""


class SimCell(Robot, Protocol):
    """A simulated cell: a robot plus its task, cycles, camera and injectable faults."""

    name: str
    dt_ns: int  # servo period
    supported_faults: frozenset[str]

    def step(self) -> None:
        """Advance physics by one servo period."""

    def observe(self) -> Observation:
        """What the policy sees now (joint state, camera measurements)."""

    def begin_cycle(self, cycle: int) -> None:
        """Set up the next cycle (a new part, the next turn)."""

    def cycle_finished(self) -> bool:
        """Whether the current cycle's motion is over."""

    def end_cycle(self) -> dict:
        """Close the cycle and return its outcome: ``success`` plus measured values (SI)."""

    def context(self) -> dict:
        """Calibration, fixture datum and other context a record needs to be read later."""
