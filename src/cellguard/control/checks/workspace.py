"""Workspace box for the tool point [m]: a category 2 stop that ends inside the box, from look-ahead.

After tracking, where a stop from the setpoint could end is checked: the tool coasts at most
v (T/2 + jerk ramp) while the slowest joint brakes for T = |v| / a_max. Before tracking, the stop
is held while the reference still points outside the box.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from cellguard.control.checks.check import Check, Stop, Tick
from cellguard.control.config import Box
from cellguard.control.events import EventKind
from cellguard.embodiment import Profile

STOP = Stop(2, EventKind.WORKSPACE_STOP, "workspace box")


def _outside(point, lo, hi) -> bool:
    (x, y, z), (x0, y0, z0), (x1, y1, z1) = point, lo, hi
    return x < x0 or x > x1 or y < y0 or y > y1 or z < z0 or z > z1


class WorkspaceLookahead(Check):
    """After tracking: stop if the tool point could leave ``box`` before a stop from the setpoint ends."""

    def __init__(self, box: Box, profile: Profile):
        self._lo, self._hi = tuple(map(float, box[0])), tuple(map(float, box[1]))
        a = profile.array("acceleration")
        self._inv_a = (1.0 / a).tolist()
        self._t_jerk = float((a / profile.array("jerk")).max())

    def request(self, tick: Tick) -> Stop | None:
        x, y, z = tick.tip
        vx, vy, vz = tick.tip_v
        t_stop = max([abs(v) * ia for v, ia in zip(tick.v, self._inv_a)])
        k = 0.5 * t_stop + self._t_jerk
        return STOP if _outside((x + vx * k, y + vy * k, z + vz * k), self._lo, self._hi) else None


class WorkspaceHold(Check):
    """Before tracking: keep a workspace stop while the reference's tool point lies outside ``box``."""

    def __init__(self, box: Box, tool: Callable[[np.ndarray], np.ndarray]):
        self._lo, self._hi, self._tool = tuple(map(float, box[0])), tuple(map(float, box[1])), tool

    def request(self, tick: Tick) -> Stop | None:
        if tick.stop_kind != EventKind.WORKSPACE_STOP or not tick.finite:
            return None
        return STOP if _outside(self._tool(tick.reference), self._lo, self._hi) else None
