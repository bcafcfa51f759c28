"""Building the guard layer for a cell from its ``guard:`` settings (``GuardConfig``)."""

from __future__ import annotations

import numpy as np

from cellguard.control.config import GuardConfig
from cellguard.control.guard import Guard
from cellguard.errors import ConfigError

def build_guard(cell, settings: GuardConfig | None = None, q0: np.ndarray | None = None) -> Guard:
    """The guard layer for ``cell``, with its kinematics and workspace box if it has them, at rest at ``q0``
    (default: the measured pose).

    The tool model is the cell's ``kinematics`` (an ``embodiment.Kinematics`` of its nominal MJCF)
    where it offers one, else its ``tool_point``. The box is the scenario's if it sets one, else the
    cell's; it is checked only where there is a tool model.
    """
    config = settings or GuardConfig()
    kinematics = getattr(cell, "kinematics", None)
    tool = kinematics.tool_point if kinematics is not None else getattr(cell, "tool_point", None)
    unchecked = [key for key in ("box", "tool_speed_max") if tool is None and getattr(config, key) is not None]
    if unchecked:  # accepted, recorded as in force and never checked
        raise ConfigError(f"guard.{unchecked[0]}: cell {cell.profile.robot} has no tool model to check it against; "
                          "remove it")
    box = config.box if config.box is not None else getattr(cell, "workspace_box", None)
    config = config.model_copy(update={"box": box if tool is not None else None})
    return Guard(cell.profile, cell.read().q if q0 is None else q0, cell.dt_ns, config, tool=tool)
