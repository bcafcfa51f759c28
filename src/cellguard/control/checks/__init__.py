"""The envelope's checks, one module each, registered here in the order they are asked.

Three phases per servo tick: ``stops`` before tracking (any may ask for a stop), ``speeds``
while tracking (tool-speed caps, the lowest wins) and ``after`` on the setpoint just computed.
A new check is one module implementing ``Check.request`` and one line below.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cellguard.control.checks.check import Check, SpeedCap, Stop, Tick
from cellguard.control.checks.effort import EffortLimit
from cellguard.control.checks.finite import FiniteReference
from cellguard.control.checks.safety_input import ProtectiveStopInput, ReducedSpeedInput
from cellguard.control.checks.tool_speed import ToolSpeedCap
from cellguard.control.checks.uncertainty import UncertaintyGate, UncertaintyHold
from cellguard.control.checks.watchdog import Watchdog
from cellguard.control.checks.workspace import WorkspaceHold, WorkspaceLookahead
from cellguard.control.config import GuardConfig
from cellguard.control.tracker import Tracker
from cellguard.embodiment import Profile

__all__ = ["Check", "Checks", "SpeedCap", "Stop", "Tick", "build_checks"]


@dataclass(frozen=True)
class Checks:
    """The checks of one envelope, per phase, in the order they are asked."""

    stops: tuple[Check, ...]
    speeds: tuple[Check, ...]
    after: tuple[Check, ...]


def build_checks(profile: Profile, config: GuardConfig, dt_ns: int,
                 tool: Callable[[np.ndarray], np.ndarray] | None, tracker: Tracker) -> Checks:
    """The checks ``config`` asks for; the box needs ``tool`` (joint positions (D,) -> tool point (3,) [m]) and
    the envelope's ``tracker`` (the stop it would run)."""
    c = config
    stops: list[Check] = [ProtectiveStopInput(), FiniteReference(),
                          EffortLimit(profile, c.effort_fraction, c.effort_hold_s, dt_ns),
                          Watchdog(c.watchdog_s, c.watchdog_category)]
    speeds: list[Check] = [ReducedSpeedInput(c.reduced_speed)]
    after: list[Check] = []
    if c.uncertainty_threshold is not None:
        if c.uncertainty_action == "hold":
            stops.append(UncertaintyHold(c.uncertainty_threshold))
        else:
            speeds.append(UncertaintyGate(c.uncertainty_threshold, c.reduced_speed))
    if c.tool_speed_max is not None:
        speeds.append(ToolSpeedCap(c.tool_speed_max))
    if c.box is not None:
        if tool is None:
            raise ValueError("box: a tool model (forward kinematics) is needed to check the tool point")
        stops.append(WorkspaceHold(c.box, tool, tracker))
        after.append(WorkspaceLookahead(c.box, profile, tool, tracker))
    return Checks(tuple(stops), tuple(speeds), tuple(after))
