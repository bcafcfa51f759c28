"""The ``guard:`` section of a scenario file, and building the guard layer for a cell.

``GuardSettings`` is the scenario's name for ``GuardConfig``: one frozen configuration, no copy.
"""

from __future__ import annotations

from cellguard.control.config import GuardConfig
from cellguard.control.guard import Guard

GuardSettings = GuardConfig


def build_guard(cell, settings: GuardConfig | None = None) -> Guard:
    """The guard layer for ``cell``, with its forward kinematics and workspace box if it has them.

    The box is the scenario's if it sets one, else the cell's; it is checked only where the cell
    has a tool model (``tool_point``).
    """
    config = settings or GuardConfig()
    tool = getattr(cell, "tool_point", None)
    box = config.box if config.box is not None else getattr(cell, "workspace_box", None)
    config = config.model_copy(update={"box": box if tool is not None else None})
    return Guard(cell.profile, cell.read().q, cell.dt_ns, config, tool=tool)
