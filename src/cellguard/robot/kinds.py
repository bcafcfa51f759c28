"""Kinds found by discovery: each module of a package (``robot/faults``, ``robot/process``) may define kinds, so a
new kind is one new file and no list to edit. A kind is a pydantic class of the package's base, defined in that
module, whose ``tag`` field (``kind: Literal["a_name"]``) is the name scenario files give it."""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Iterable, Sequence
from typing import Literal, get_args, get_origin


def discover(package: str, path: Iterable[str], base: type, what: str, tag: str = "kind",
             first: Sequence[str] = ()) -> dict[str, type]:
    """Every kind in the modules of ``package`` (found on ``path``, its ``__path__``), by name: those named in
    ``first`` in that order (the order scenario errors list them in), then the others by name. TypeError naming
    the class (``what``: "fault kind") whose ``tag`` is not one name, or both classes that take one name."""
    found: dict[str, type] = {}
    for module in sorted(m.name for m in pkgutil.iter_modules(path)):
        defined = importlib.import_module(f"{package}.{module}")
        for cls in vars(defined).values():
            if not (isinstance(cls, type) and issubclass(cls, base) and cls.__module__ == defined.__name__
                    and tag in cls.model_fields):
                continue  # imported from elsewhere, or a base with no name of its own (``IntermittentOffset``)
            where = f"{cls.__module__}.{cls.__name__}"
            names = get_args(cls.model_fields[tag].annotation)
            if get_origin(cls.model_fields[tag].annotation) is not Literal or len(names) != 1 \
                    or not isinstance(names[0], str):
                raise TypeError(f"{what} {where}: {tag} must be Literal['a_name']")
            if names[0] in found:
                raise TypeError(f"{what} {names[0]!r} is defined twice: {found[names[0]].__module__}."
                                f"{found[names[0]].__name__} and {where}")
            found[names[0]] = cls
    place = {name: i for i, name in enumerate(first)}
    return dict(sorted(found.items(), key=lambda item: (place.get(item[0], len(place)), item[0])))
