"""Registered simulated cells: the built-in ones, and those a plugin registers; an unknown name lists the rest.

A new cell is one file in its own package, registered in that package's metadata under the entry-point
group ``cellguard.cells`` (the name is the cell's ``name``, the value its class), as LeRobot finds robot
plugins: ``make_cell`` and every command that opens a record of the cell later (``identify``, ``replay``)
find it in any process, with no edit to cellguard. A plugin is imported only when its cell is asked for.
"""

from __future__ import annotations

import inspect
import sys
from collections.abc import Callable
from importlib.metadata import EntryPoint, entry_points

from cellguard.errors import ConfigError, UnknownNameError
from cellguard.robot.arm_cell import ArmPickPlace
from cellguard.robot.protocol import SimCell
from cellguard.robot.quadruped_cell import QuadrupedTurns
from cellguard.robot.so101_cell import SO101PickPlace

CELLS: dict[str, type] = {ArmPickPlace.name: ArmPickPlace, QuadrupedTurns.name: QuadrupedTurns,
                          SO101PickPlace.name: SO101PickPlace}
CELL_PLUGINS = "cellguard.cells"  # the entry-point group of cells other packages add


def cell_names() -> list[str]:
    """Every cell ``make_cell`` can build: the built-in ones, then the plugins'."""
    return [*CELLS, *(name for name in plugins(CELL_PLUGINS) if name not in CELLS)]


def make_cell(name: str, seed: int = 0):
    """Build the simulated cell ``name`` with its random generator seeded by ``seed``. A built-in cell's name is
    always the built-in cell (a plugin registering it is never loaded)."""
    if name in CELLS:
        return CELLS[name](seed=seed)
    cls = load_plugin(CELL_PLUGINS, name, "cell")
    if cls is None:
        raise UnknownNameError("cell", name, cell_names())
    if getattr(cls, "name", None) != name:
        raise ConfigError(f"cell {name!r}: its plugin's class {cls.__module__}.{cls.__qualname__} is named "
                          f"{getattr(cls, 'name', None)!r}; the entry point's name must be the cell's name")
    file = getattr(sys.modules.get(cls.__module__), "__file__", None)  # the file to fix, where there is one
    where = f"{cls.__module__} ({file})" if file else cls.__module__
    return from_plugin(lambda: cls(seed=seed), SimCell, f"cell {name!r}: its plugin {where}")


def from_plugin(make: Callable[[], object], protocol: type, what: str):
    """What ``make`` (a plugin's code) returns, checked to have every member of ``protocol``; ConfigError naming
    ``what`` when it raises or returns something else (a plugin's traceback, or an AttributeError deep in a run)."""
    try:
        made = make()
    except ConfigError as exc:  # cellguard's own check of what the plugin gave it (a profile that does not fit)
        raise ConfigError(f"{what}: {exc}") from None
    except Exception as exc:  # any error of a plugin's own code is the plugin's, named here
        raise ConfigError(f"{what} failed: {type(exc).__name__}: {exc}") from None
    members = {n for n in dir(protocol) if not n.startswith("_")}
    for base in protocol.__mro__:
        members |= set(getattr(base, "__annotations__", {}))
    absent = object()  # looked up without running a property (one that raises is the plugin's, not a traceback)
    missing = sorted(m for m in members if inspect.getattr_static(made, m, absent) is absent)
    if missing:
        raise ConfigError(f"{what} returned a {type(made).__name__}, not a {protocol.__name__}: it has no "
                          f"{', '.join(missing)}")
    return made


def plugins(group: str) -> dict[str, EntryPoint]:
    """The entry points of ``group`` in the installed distributions, by name (not loaded)."""
    return {ep.name: ep for ep in entry_points(group=group)}


def load_plugin(group: str, name: str, what: str):
    """What the entry point ``name`` of ``group`` names, or None if no package registers it; ConfigError naming
    the plugin when it cannot be imported (one line, not a plugin's traceback), or naming both when two
    distributions register ``name`` with other values (which one won followed the order the folders were listed
    in, so the same record could read as another robot on another host; other names are not affected)."""
    found = [ep for ep in entry_points(group=group) if ep.name == name]
    if not found:
        return None
    ep = found[0]
    others = sorted({e.value for e in found} - {ep.value})
    if others:
        raise ConfigError(f"{group} {name!r}: registered twice, as {ep.value} and as {others[0]}; uninstall one of "
                          f"the two plugins")
    try:
        return ep.load()
    except Exception as exc:  # any error of a plugin's import is the plugin's, named here
        raise ConfigError(f"{what} {name!r}: its plugin {ep.value} (entry point group {group}) cannot be loaded: "
                          f"{type(exc).__name__}: {exc}") from None
