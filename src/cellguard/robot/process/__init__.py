"""Process change kinds for simulated cells, registered in one place: ``PROCESS_CHANGES`` maps kind to class."""

from collections.abc import Sequence
from typing import Annotated, Union

from pydantic import Field

from cellguard.robot.process.base import ProcessChange
from cellguard.robot.process.payload import Payload
from cellguard.robot.process.warmup import Warmup

_KINDS = (Payload, Warmup)
PROCESS_CHANGES: dict[str, type[ProcessChange]] = {k.model_fields["kind"].annotation.__args__[0]: k for k in _KINDS}
AnyProcessChange = Annotated[Union[_KINDS], Field(discriminator="kind")]  # noqa: UP007


def declared_changes(changes: Sequence[ProcessChange], cycle: int) -> list[dict]:
    """The declared changes that have happened by ``cycle``: what the record's context carries."""
    return [c.declaration() for c in changes if c.declared and c.at_cycle <= cycle]


__all__ = ["PROCESS_CHANGES", "AnyProcessChange", "ProcessChange", "declared_changes"]
