"""Options written into a source string, ``TARGET?key=value&...``, and the numbers they carry: one parser
and one range check for policy sources and robot bridges alike (a shared leaf: both layers read it)."""

from __future__ import annotations

from urllib.parse import unquote, unquote_plus

from cellguard.errors import ConfigError


def split_options(arg: str, allowed: dict[str, str] | None, where: str, usage: str) -> tuple[str, dict[str, str]]:
    """``"TARGET?k=v&k2=v2"`` -> (TARGET, options), percent-decoded. ``allowed`` (name -> what it is) refuses any
    other key, listing them; None takes every key (a bridge hands the rest to its robot's config). A repeated key is
    refused (the last silently won), and so is a missing target (``usage`` says how to write it)."""
    target, _, query = arg.partition("?")
    options: dict[str, str] = {}
    for key, value in parse_query(query):
        if allowed is not None and key not in allowed:
            known = ", ".join(f"{k} ({v})" for k, v in allowed.items())
            raise ConfigError(f"{where}: unknown option {key!r}; options: {known}")
        if key in options:
            raise ConfigError(f"{where}: option {key!r} is given twice ({options[key]!r} and {value!r}); give it once")
        options[key] = value
    if not target:
        raise ConfigError(f"{where}: missing target, write {usage}")
    return target, options


FILE_OPTIONS = frozenset({"map", "units"})  # options whose value names a file (a policy's action map, a bridge's units)


def parse_query(query: str) -> list[tuple[str, str]]:
    """``k=v&k2=v2`` -> [(k, v), (k2, v2)] as ``parse_qsl`` reads them (a ``+`` is a space: ``prompt=pick+up``), but
    a file's name (``FILE_OPTIONS``) percent-decoded only: ``?map=a+b.yaml`` named a file ``a b.yaml``. A key
    without ``=`` has the value ''."""
    pairs = ((unquote_plus(key), value) for key, _, value in (part.partition("=") for part in query.split("&") if part))
    return [(key, (unquote if key in FILE_OPTIONS else unquote_plus)(value)) for key, value in pairs]


def bounded_float(value: object, field: str, lo: float, hi: float) -> float:
    """A number written as text or carried in metadata (``"0.02"``, ``0.02``) that lies in [lo, hi].

    The one gate for numbers that arrive as strings: option values (``?dt=``, ``?hz=``) and model or
    server metadata (``cellguard.dt_s``, ``dt_s``). A non-number, a boolean, NaN, infinity or a value
    out of range raises ConfigError naming ``field`` and the range.
    """
    if isinstance(value, bool) or not isinstance(value, (str, int, float)):
        raise ConfigError(f"{field}: expected a number in [{lo:g}, {hi:g}], got {value!r}")
    if isinstance(value, str) and not value.isascii():  # float() reads other scripts' digits ("٠.٠٢"); no file does
        raise ConfigError(f"{field}: {value!r} is not written in ASCII digits; expected a number in [{lo:g}, {hi:g}]")
    try:
        number = float(value)
    except (ValueError, OverflowError):
        raise ConfigError(f"{field}: {value!r} is not a number; expected one in [{lo:g}, {hi:g}]") from None
    if not lo <= number <= hi:  # NaN fails this too
        raise ConfigError(f"{field}: {value!r} is outside [{lo:g}, {hi:g}]")
    return number
