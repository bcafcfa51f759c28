"""Kinds found by discovery: each module of a package (``robot/faults``, ``robot/process``, ``robot/recovery``) may
define kinds, so a new kind is one new file and no list to edit (which modules are imported, and how a broken one is
refused: ``cellguard.plugins``). A kind is a pydantic class of the package's base, defined in that module, whose
``tag`` field (``kind: Literal["a_name"]``) is the name scenario files give it."""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from types import ModuleType
from typing import Literal, get_args, get_origin

from cellguard import plugins


def discover(package: str, path: Iterable[str], base: type, what: str, tag: str = "kind",
             first: Sequence[str] = ()) -> dict[str, type]:
    """Every kind in the modules of ``package`` (found on ``path``, its ``__path__``), by name: those named in
    ``first`` in that order (the order scenario errors list them in), then the others by name. PluginError naming
    the class (``what``: "fault kind") whose ``tag`` is not one name, or both classes that take one name."""

    def kinds_in(module: ModuleType) -> Iterator[tuple[str, str, type]]:
        for cls in vars(module).values():
            if not (isinstance(cls, type) and issubclass(cls, base) and cls.__module__ == module.__name__
                    and tag in cls.model_fields):
                continue  # imported from elsewhere, or a base with no name of its own (``IntermittentOffset``)
            where = f"{cls.__module__}.{cls.__name__}"
            names = get_args(cls.model_fields[tag].annotation)
            if get_origin(cls.model_fields[tag].annotation) is not Literal or len(names) != 1 \
                    or not isinstance(names[0], str):
                raise plugins.refused(module, f"{what} {where}: {tag} must be Literal['a_name']")
            try:  # a field pydantic cannot build failed every scenario later, in a traceback, used or not
                cls.model_rebuild()
            except Exception as exc:  # noqa: BLE001 (pydantic's errors have no one base)
                raise plugins.refused(module, f"{what} {where}: {' '.join(str(exc).split())}") from exc
            yield names[0], where, cls

    found = plugins.discover(package, path, kinds_in, what)
    place = {name: i for i, name in enumerate(first)}
    return dict(sorted(found.items(), key=lambda item: (place.get(item[0], len(place)), item[0])))
