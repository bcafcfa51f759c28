"""Robot bridges by scheme: a scenario's ``robot: SCHEME:TARGET?options`` names one.

``BRIDGES`` maps a scheme to a factory taking the text after ``SCHEME:``; each factory imports
its heavy dependency lazily. ``make_robot(spec)`` parses the spec; an unknown scheme lists the rest.
"""

from __future__ import annotations

from collections.abc import Callable

from cellguard.errors import UnknownNameError


def _lerobot(arg: str):
    from cellguard.robot.bridges.lerobot import make_lerobot_robot

    return make_lerobot_robot(arg)


BRIDGES: dict[str, Callable[[str], object]] = {"lerobot": _lerobot}


def make_robot(spec: str):
    """The robot named by ``spec`` (``scheme:target?k=v&...``), connected and ready for ``read``/``write``."""
    scheme, _, arg = spec.partition(":")
    try:
        factory = BRIDGES[scheme]
    except KeyError:
        raise UnknownNameError("robot bridge", scheme, list(BRIDGES)) from None
    return factory(arg)
