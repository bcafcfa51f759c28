"""Policy sources by scheme: ``scripted``, ``replay:FILE``, and the adapters' schemes.

``make_policy(spec, cell)`` parses the scenario's ``policy:`` string; an unknown scheme lists
the known ones.
"""

from __future__ import annotations

from collections.abc import Callable

from cellguard.errors import ConfigError, UnknownNameError
from cellguard.policy.protocol import Policy


def _scripted(arg: str, cell) -> Policy:
    if arg:
        raise ConfigError(f"policy: 'scripted' takes no argument, got 'scripted:{arg}'")
    try:
        factory = SCRIPTED[cell.name]
    except KeyError:
        raise UnknownNameError("scripted policy for cell", cell.name, list(SCRIPTED)) from None
    return factory(cell)


def _scripted_arm(cell) -> Policy:
    from cellguard.policy.scripted_arm import ScriptedArmPolicy

    return ScriptedArmPolicy(calibration=cell.context())


SCRIPTED: dict[str, Callable[[object], Policy]] = {"arm-pick-place": _scripted_arm}
SCHEMES: dict[str, Callable[[str, object], Policy]] = {"scripted": _scripted}


def make_policy(spec: str, cell) -> Policy:
    """Build the policy named by ``spec`` (``scheme`` or ``scheme:argument``) for ``cell``."""
    scheme, _, arg = spec.partition(":")
    try:
        factory = SCHEMES[scheme]
    except KeyError:
        raise UnknownNameError("policy source", scheme, list(SCHEMES)) from None
    return factory(arg, cell)
