"""What a robot offers cellguard, the extra calls a simulated cell offers the tick loop, and link errors."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from cellguard.embodiment import Profile
from cellguard.errors import CellguardError
from cellguard.robot.state import Observation, State


@dataclass(frozen=True)
class SafetyInputs:
    """What the cell's certified safety controller tells the guard layer, read every tick.

    ``stop``: a protective or emergency stop in force, with its IEC 60204-1 category (0, 1, 2),
    or None. ``reduced_speed``: the controller asks for reduced speed (250 mm/s at the tool).
    ``asked_by``: who asked ``stop`` when the tick loop adds a stop of its own (operator stop, robot
    link fault, watchdog, recovery hold) that is stricter than the controller's; None: the controller.
    """

    stop: int | None = None
    reduced_speed: bool = False
    asked_by: str | None = None


class Robot(Protocol):
    """A robot at servo rate: MuJoCo cells here; a hardware bridge has the same members (``make_bridge`` refuses
    one that lacks any: the loop, the policy and the record read every one)."""

    name: str  # the robot in the record's context; a bridge's need not be a cell's (``lerobot:TYPE``)
    profile: Profile
    dt_ns: int  # servo period

    def read(self) -> State:
        """The measured state now."""

    def write(self, setpoint: np.ndarray) -> np.ndarray:
        """Command joint positions (dof,); return what was actually sent after the drive's own clipping."""

    def safety(self) -> SafetyInputs:
        """The certified safety controller's inputs now (simulated in the cells)."""

    def set_power(self, on: bool) -> None:
        """Drive power: off removes torque and engages the brakes (stop categories 0 and 1)."""

    def observe(self) -> Observation:
        """What the policy sees now (joint state, camera measurements)."""

    def context(self) -> dict:
        """Calibration, fixture datum and other context a record needs to be read later."""


class SimCell(Robot, Protocol):
    """A simulated cell: a robot plus its task, cycles, camera and injectable faults."""

    supported_faults: frozenset[str]

    def step(self) -> None:
        """Advance physics by one servo period."""

    def begin_cycle(self, cycle: int) -> None:
        """Set up the next cycle (a new part, the next turn)."""

    def cycle_finished(self) -> bool:
        """Whether the current cycle's motion is over."""

    def cycle_under_way(self) -> bool:
        """Whether the current cycle's motion has begun (a run that stopped mid-cycle left it so)."""

    def end_cycle(self) -> dict:
        """Close the cycle and return its outcome: ``success`` plus measured values (SI)."""


class RobotLinkError(CellguardError):
    """A robot bridge's read or write failed; ``kind`` names the event, ``lost`` says the link is gone."""

    def __init__(self, kind: str, message: str, lost: bool = False):
        super().__init__(message)
        self.kind, self.lost = kind, lost
