"""What a robot reports each servo tick, and what a cell shows the policy."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np


class State(NamedTuple):
    """Measured joint state at ``t_ns``; arrays shape (dof,), profile joint order, SI units.

    A named tuple, not a frozen dataclass: one is built every servo tick, and a frozen dataclass's
    ``__init__`` costs four times as much."""

    t_ns: int
    q: np.ndarray  # [rad] or [m]
    qd: np.ndarray  # [rad/s] or [m/s]
    effort: np.ndarray  # [N·m] or [N]
    current: np.ndarray  # [A]


@dataclass(frozen=True)
class Observation:
    """What a policy sees: the joint state plus named measurements (camera, gripper, commands).

    ``measurements`` maps a name to a float64 array, e.g. ``"part_in_camera"`` (3,) [m] in the
    camera frame. The policy converts with its own calibration; the cell never tells it truth.
    """

    t_ns: int
    q: np.ndarray
    qd: np.ndarray
    measurements: dict[str, np.ndarray] = field(default_factory=dict)
