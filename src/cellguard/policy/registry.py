"""Policy sources by scheme: ``scripted``, ``replay:FILE``, and the adapters' schemes.

``make_policy(spec, cell)`` parses the scenario's ``policy:`` string; an unknown scheme lists
the known ones. ``scripted`` is the cell's taught program: a plugin cell's comes from the entry-point
group ``cellguard.scripted_policies`` of its package.
"""

from __future__ import annotations

from collections.abc import Callable

from cellguard.errors import ConfigError, UnknownNameError
from cellguard.policy.protocol import Policy
from cellguard.robot.registry import from_plugin, load_plugin, plugins


def _scripted(arg: str, cell) -> Policy:
    if arg:
        raise ConfigError(f"policy: 'scripted' takes no argument, got 'scripted:{arg}'")
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
def _onnx(arg: str, cell) -> Policy:
    from cellguard.policy.onnx import make_onnx_policy

    return make_onnx_policy(arg, cell)


def _openpi(arg: str, cell) -> Policy:
    from cellguard.policy.openpi import make_openpi_policy

    return make_openpi_policy(arg, cell)


def _lerobot(arg: str, cell) -> Policy:
    from cellguard.policy.lerobot import make_lerobot_policy

    return make_lerobot_policy(arg, cell)


def _replay(arg: str, cell) -> Policy:
    from cellguard.policy.replay import make_replay_policy

    return make_replay_policy(arg, cell)


SCHEMES: dict[str, Callable[[str, object], Policy]] = {"scripted": _scripted, "replay": _replay, "onnx": _onnx,
                                                       "openpi": _openpi,
                                                       "lerobot": _lerobot}


def make_policy(spec: str, cell) -> Policy:
    """Build the policy named by ``spec`` (``scheme`` or ``scheme:argument``) for ``cell``."""
    scheme, _, arg = spec.partition(":")
    try:
        factory = SCHEMES[scheme]
    except KeyError:
        raise UnknownNameError("policy source", scheme, list(SCHEMES)) from None
    return factory(arg, cell)
