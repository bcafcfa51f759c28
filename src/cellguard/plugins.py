"""Plugins found by discovery: every module of a plugin package (fault kinds, process changes, recovery behaviours,
gate metrics) is imported and what it defines is taken by name, so a new plugin is one new file and no list to edit.

Only a module that can be a plugin is imported: one whose name is an identifier not starting with ``_``, not a
sub-package. An editor's or a file manager's copy (``friction_step copy.py``, ``friction_step-old.py``) would define
its kind a second time, and a helper (``_shared.py``) is no plugin. A module that cannot be imported, or that takes
a name another module took, is one ``PluginError`` naming its file: discovery runs when its package is imported
(faults, process changes and recoveries with cellguard, so every command; gate metrics with the release commands),
and ``cellguard.entry`` prints it in one line (exit 2) instead of a traceback.
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Callable, Iterable
from types import ModuleType
from typing import TypeVar

from cellguard.errors import CellguardError

T = TypeVar("T")


class PluginError(CellguardError):
    """A plugin module that cannot be taken; the message starts with its file."""


def refused(module: ModuleType, cause: str) -> PluginError:
    """The error for ``module`` (a plugin module, or the module of a plugin's class) that ``cause`` says is wrong."""
    return PluginError(f"{module.__file__}: {cause}")


def discover(package: str, path: Iterable[str], take: Callable[[ModuleType], Iterable[tuple[str, str, T]]],
             what: str) -> dict[str, T]:
    """What the plugin modules of ``package`` (found on ``path``, its ``__path__``) define, by name: in the order of
    the modules' names, each module's in the order ``take`` gives them. ``take(module)`` gives ``(name, where,
    plugin)`` (``where`` names the plugin in an error) and raises ``refused`` for a module it cannot take. A name
    two plugins take is refused naming both (``what``: "fault kind")."""
    found: dict[str, tuple[str, str, T]] = {}
    for info in sorted(pkgutil.iter_modules(path), key=lambda m: m.name):
        if info.ispkg or not info.name.isidentifier() or info.name.startswith("_"):
            continue
        module = _load(package, info)
        for name, where, plugin in take(module):
            if name in found:  # both files named: the one sorted first may be the stray copy
                raise refused(module, f"{what} {name!r} is defined twice: {found[name][0]} ({found[name][1]}) and "
                                      f"{where}")
            found[name] = (where, module.__file__, plugin)
    return {name: plugin for name, (_, _, plugin) in found.items()}


def _load(package: str, info: pkgutil.ModuleInfo) -> ModuleType:
    """The module ``info`` names, imported; any failure (a missing dependency, a syntax error, a module that exits)
    as one line naming its file. A PluginError it raised itself (a plugin it imports) is passed on as it is."""
    name = f"{package}.{info.name}"
    try:
        return importlib.import_module(name)
    except PluginError:
        raise
    except (Exception, SystemExit) as exc:
        cause = " ".join(f"{type(exc).__name__}: {exc}".split())  # a message of several lines, as one
        raise PluginError(f"{info.module_finder.find_spec(name).origin}: cannot be imported: {cause}") from exc
