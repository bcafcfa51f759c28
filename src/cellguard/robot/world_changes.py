"""Faults and process changes applied together, so that changes of one setting compose.

Each fault and process change states its effect through the cell's setters, as an absolute value
from the commissioned one (its "off" value before it starts: offset 0, factor 1). Called one after
another on the cell, the last call won: two fixture shifts cancelled, a warm-up reset a growing
friction, two servo-gain faults on one joint kept only the second, and the summary's ground truth
listed all of them as injected. Here the calls are collected first and composed per setting and
joint (offsets and payloads add, friction and gain factors multiply), and the cell gets one value.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

ADDED = frozenset({"set_fixture_offset", "set_camera_offset", "set_tool_offset", "set_part_offset", "set_payload"})
MULTIPLIED = frozenset({"set_friction_scale", "set_servo_gain"})  # per joint


class _Effects:
    """Stands in for the cell while the changes state their effects; ``profile`` as the cell's."""

    def __init__(self, cell):
        self.profile = cell.profile
        self._sums: dict[str, np.ndarray] = {}
        self._products: dict[tuple[str, str], float] = {}

    def __getattr__(self, setter: str):
        if setter in ADDED:
            return lambda value: self._add(setter, value)
        if setter in MULTIPLIED:
            return lambda joint, factor: self._multiply(setter, joint, factor)
        raise AttributeError(f"{setter}: not a setter a fault or process change may call")

    def _add(self, setter: str, value) -> None:
        value = np.asarray(value, dtype=np.float64)
        self._sums[setter] = self._sums.get(setter, 0.0) + value

    def _multiply(self, setter: str, joint: str, factor: float) -> None:
        self._products[setter, joint] = self._products.get((setter, joint), 1.0) * float(factor)

    def refused_by(self, cell) -> str | None:
        """Why ``cell`` cannot take the composed values (a part of no mass), or None."""
        payload = self._sums.get("set_payload")
        return None if payload is None else cell.payload_problem(float(payload))

    def apply_to(self, cell) -> None:
        for setter, value in self._sums.items():
            getattr(cell, setter)(value if value.ndim else float(value))
        for (setter, joint), factor in self._products.items():
            getattr(cell, setter)(joint, factor)


def apply_world_changes(cell, changes: Iterable, cycle: int) -> None:
    """Apply every fault and process change in ``changes`` to ``cell`` for ``cycle``, composed per setting."""
    effects = _Effects(cell)
    for change in changes:
        change.apply(effects, cycle)
    effects.apply_to(cell)


def first_refused(cell, changes: Sequence) -> tuple[int, str] | None:
    """The first of ``changes`` (by ``at_cycle``) whose cycle ``cell`` cannot take once every change in force then is
    composed, with why; None if it takes them all. Payloads are steps, so their sum is lowest where one starts."""
    for i in sorted(range(len(changes)), key=lambda k: changes[k].at_cycle):
        effects = _Effects(cell)
        for change in changes:
            change.apply(effects, changes[i].at_cycle)
        why = effects.refused_by(cell)
        if why is not None:
            return i, why
    return None
