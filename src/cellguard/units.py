"""Quantities with units at the edge of cellguard, SI inside.

Profile and scenario files write a limit as ``"3.0 rad/s"`` or ``"170 deg"``; a bare number
is refused because a number without its unit is how a degree becomes a radian on site.
"""

from __future__ import annotations

import math
import re

from cellguard.errors import ConfigError

# unit -> (dimension, factor to SI)
_UNITS: dict[str, tuple[str, float]] = {
    "rad": ("angle", 1.0),
    "deg": ("angle", math.pi / 180.0),
    "m": ("length", 1.0),
    "mm": ("length", 1e-3),
    "rad/s": ("angle/s", 1.0),
    "deg/s": ("angle/s", math.pi / 180.0),
    "m/s": ("length/s", 1.0),
    "mm/s": ("length/s", 1e-3),
    "rad/s^2": ("angle/s^2", 1.0),
    "deg/s^2": ("angle/s^2", math.pi / 180.0),
    "m/s^2": ("length/s^2", 1.0),
    "rad/s^3": ("angle/s^3", 1.0),
    "deg/s^3": ("angle/s^3", math.pi / 180.0),
    "m/s^3": ("length/s^3", 1.0),
    "N*m": ("torque", 1.0),
    "N": ("force", 1.0),
    "N*m/A": ("torque/A", 1.0),
    "N/A": ("force/A", 1.0),
    "N*m*s/rad": ("damping", 1.0),
    "s": ("time", 1.0),
    "ms": ("time", 1e-3),
    "kg": ("mass", 1.0),
    "kg*m^2": ("inertia", 1.0),
}

_NUMBER = r"[-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][-+]?[0-9]+)?"  # ASCII digits, as written in a file
_GLUED = re.compile(f"({_NUMBER})(\\S+)")  # a number, then its unit
_PLAIN = re.compile(_NUMBER)


def parse_quantity(text: object, field: str, dimensions: tuple[str, ...]) -> float:
    """Return the SI value of ``"<number> <unit>"``; the unit must have one of ``dimensions``."""
    if isinstance(text, bool) or not isinstance(text, (str, int, float)):
        raise ConfigError(f"{field}: expected '<number> <unit>', got {text!r}")
    parts = str(text).split()
    if len(parts) != 2:
        glued = _GLUED.fullmatch(str(text).strip())
        if glued and glued[2] in _UNITS:  # "0.2N*m": the unit is there, the space is not
            raise ConfigError(f"{field}: no space between the number and the unit in {text!r}; write "
                              f"'{glued[1]} {glued[2]}'")
        allowed = [u for u, (d, _) in _UNITS.items() if d in dimensions]
        raise ConfigError(f"{field}: missing unit in {text!r}; write e.g. '{text} {allowed[0]}' (units: {', '.join(allowed)})")
    number, unit = parts
    try:
        value = float(number)
    except ValueError:
        raise ConfigError(f"{field}: {number!r} is not a number") from None
    if not math.isfinite(value):
        raise ConfigError(f"{field}: {value} is not finite")
    if not _PLAIN.fullmatch(number):  # float() reads "3_0" as 30, and digits of other scripts
        raise ConfigError(f"{field}: {number!r} is not a number (digits 0-9, a dot, an exponent)")
    if unit not in _UNITS or _UNITS[unit][0] not in dimensions:
        allowed = [u for u, (d, _) in _UNITS.items() if d in dimensions]
        raise ConfigError(f"{field}: unit {unit!r} does not fit; allowed: {', '.join(allowed)}")
    return value * _UNITS[unit][1]

