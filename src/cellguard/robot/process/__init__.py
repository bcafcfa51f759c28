"""Process change kinds for simulated cells: every module of this package that defines one (a ``ProcessChange``
with its ``kind``) is found here, so a new kind is one new file; ``PROCESS_CHANGES`` maps kind to class."""

from collections.abc import Sequence
from typing import Annotated, Union

from pydantic import Field

from cellguard.robot.kinds import discover
from cellguard.robot.process.base import ProcessChange

PROCESS_CHANGES: dict[str, type[ProcessChange]] = discover(__name__, __path__, ProcessChange, "process change kind")
AnyProcessChange = Annotated[Union[tuple(PROCESS_CHANGES.values())], Field(discriminator="kind")]  # noqa: UP007


def declared_changes(changes: Sequence[ProcessChange], cycle: int) -> list[dict]:
    """The declared changes that have happened by ``cycle``: what the record's context carries."""
    return [c.declaration() for c in changes if c.declared and c.at_cycle <= cycle]


__all__ = ["PROCESS_CHANGES", "AnyProcessChange", "ProcessChange", "declared_changes"]
