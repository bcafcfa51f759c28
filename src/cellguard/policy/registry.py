"""Policy sources by scheme: ``scripted``, ``replay:FILE``, and the adapters' schemes.

``make_policy(spec, cell, soft_margin)`` parses the scenario's ``policy:`` string; an unknown scheme lists
the known ones. ``scripted`` is the cell's taught program: a plugin cell's comes from the entry-point
group ``cellguard.scripted_policies`` of its package.

A source is a module: its factory ``(arg, cell) -> Policy`` (one that solves end-effector actions by IK takes the
keyword ``soft_margin`` too: the guard's, whose soft limits the IK keeps inside) and what it takes, ``OPTIONS`` (its
``?name=`` options, ``map`` among them for one that takes an action map) and ``TAKES_FILE`` (its argument names a file
or folder, which a release freezes by its absolute path). A new source is a new module and its line in ``SCHEMES``.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from importlib import import_module
from types import ModuleType

from cellguard.embodiment.profile import SOFT_MARGIN
from cellguard.errors import ConfigError, UnknownNameError
from cellguard.policy.protocol import Policy
from cellguard.robot.registry import from_plugin, load_plugin, plugins


def _scripted(arg: str, cell) -> Policy:
    """The cell's taught program; ``arg`` is empty (``make_policy`` refuses one: this source takes none; ``scripted:``
    is ``scripted``, as a release stores it: ``takes_nothing``)."""
    if cell.name in SCRIPTED:
        return SCRIPTED[cell.name](cell)
    factory = load_plugin(SCRIPTED_PLUGINS, cell.name, "scripted policy for cell")
    if factory is None:
        raise UnknownNameError("scripted policy for cell", cell.name,
                               [*SCRIPTED, *(n for n in plugins(SCRIPTED_PLUGINS) if n not in SCRIPTED)])
    return from_plugin(lambda: factory(cell), Policy, f"scripted policy for cell {cell.name!r}: its plugin "
                       f"{getattr(factory, '__module__', factory)}")


def _scripted_arm(cell) -> Policy:
    from cellguard.policy.scripted_arm import ScriptedArmPolicy

    return ScriptedArmPolicy(calibration=cell.context())


def _scripted_so101(cell) -> Policy:
    from cellguard.policy.scripted_arm import SO101, ScriptedArmPolicy

    return ScriptedArmPolicy(calibration=cell.context(), teaching=SO101)


def _scripted_quadruped(cell) -> Policy:
    from cellguard.policy.scripted_quadruped import ScriptedQuadrupedPolicy

    return ScriptedQuadrupedPolicy(cell.profile)


SCRIPTED: dict[str, Callable[[object], Policy]] = {"arm-pick-place": _scripted_arm,
                                                   "so101-pick-place": _scripted_so101,
                                                   "quadruped-turns": _scripted_quadruped}
# a plugin cell's taught program: entry point name = the cell's name, value = a callable cell -> Policy
SCRIPTED_PLUGINS = "cellguard.scripted_policies"
OPTIONS: dict[str, str] = {}  # what scripted takes (this module is its source): no options, no file
TAKES_FILE = False

# scheme -> "module:factory"; a module is imported only when its scheme is asked for (an adapter's extra may be absent)
SCHEMES: dict[str, str] = {"scripted": f"{__name__}:_scripted",
                           "replay": "cellguard.policy.replay:make_replay_policy",
                           "onnx": "cellguard.policy.onnx:make_onnx_policy",
                           "openpi": "cellguard.policy.openpi:make_openpi_policy",
                           "lerobot": "cellguard.policy.lerobot:make_lerobot_policy"}


def source(scheme: str) -> ModuleType:
    """The module of the policy source ``scheme``, which declares what it takes (``OPTIONS``, ``TAKES_FILE``): a
    release reads it there, so a new source needs no edit to the release code."""
    try:
        module = SCHEMES[scheme].partition(":")[0]
    except KeyError:
        raise UnknownNameError("policy source", scheme, list(SCHEMES)) from None
    try:
        return import_module(module)
    except ModuleNotFoundError as exc:  # an adapter's extra is not installed: a traceback named only the module
        raise ConfigError(f"policy source {scheme}: needs the Python package {exc.name!r}, which is not installed "
                          f"(pip install 'cellguard[{scheme}]')") from None


def takes_nothing(module) -> bool:
    """Whether a policy source takes no argument (no options, no file: scripted): its ``scheme:`` with nothing after
    the colon is the scheme alone (a release stores it so: ``scripted:`` made a second release of the same program,
    and releases an earlier version stored as ``scripted:`` still run)."""
    return not module.OPTIONS and not module.TAKES_FILE


def make_policy(spec: str, cell, soft_margin: float = SOFT_MARGIN) -> Policy:
    """Build the policy named by ``spec`` (``scheme`` or ``scheme:argument``) for ``cell``, its IK (if any) inside the
    soft limits of the run's ``guard.soft_margin`` (at the default one, a wider margin's guard held the joint short of
    a target the IK had reached: the tool missed)."""
    scheme, colon, arg = spec.partition(":")
    module = source(scheme)
    if arg and takes_nothing(module):
        raise ConfigError(f"policy: {scheme!r} takes no argument, got {spec!r}; write {scheme!r}")
    factory = getattr(module, SCHEMES[scheme].partition(":")[2])
    if "soft_margin" in inspect.signature(factory).parameters:
        return factory(arg, cell, soft_margin=soft_margin)
    return factory(arg, cell)
