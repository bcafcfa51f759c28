"""Registered simulated cells: a plain dict from name to class; an unknown name lists the rest."""

from __future__ import annotations

from cellguard.errors import UnknownNameError
from cellguard.robot.arm_cell import ArmPickPlace
from cellguard.robot.quadruped_cell import QuadrupedTurns
from cellguard.robot.so101_cell import SO101PickPlace

CELLS: dict[str, type] = {ArmPickPlace.name: ArmPickPlace, QuadrupedTurns.name: QuadrupedTurns,
                          SO101PickPlace.name: SO101PickPlace}


def make_cell(name: str, seed: int = 0):
    """Build the simulated cell ``name`` with its random generator seeded by ``seed``."""
    try:
        cls = CELLS[name]
    except KeyError:
        raise UnknownNameError("cell", name, list(CELLS)) from None
    return cls(seed=seed)
