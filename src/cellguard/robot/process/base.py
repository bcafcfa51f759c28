"""A legitimate process change in a simulated cell (a heavier product variant, a restart after
idle); one kind per module, like the faults.

Unlike a fault, a process change is something the line knows about: when ``declared`` it is
written into the record's context from its cycle on (``declaration``), so the diagnosis can
condition on it. ``declared: false`` simulates a change nobody told the record about. How the
diagnosis conditions on a declared change is the kind's own ``diagnosis`` (``diagnose/process.py``), so a
new kind is one file here.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

from pydantic import BaseModel, ConfigDict, Field


class ProcessChange(BaseModel):
    """Base of every process change kind; ``kind`` is the discriminator in scenario files."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    at_cycle: int = Field(ge=0)
    declared: bool = True
    hook: ClassVar[str] = ""  # the cell call a change of this kind needs
    # how the diagnosis conditions on it once declared: "rebase" (a lasting change of load: load-dependent features
    # get a new centre), "settle" (a passing rise of friction: friction-dependent features unwatched till back)
    diagnosis: ClassVar[str] = ""

    def apply(self, cell, cycle: int) -> None:
        """Change the simulated world for ``cycle`` (called at the start of every cycle)."""

    def declaration(self) -> dict:
        """What the record's context says of this change once it has happened."""
        return self.model_dump(mode="json", exclude={"declared"})

    @classmethod
    def describe(cls, declared: Mapping) -> str:
        """The change as a diagnosis note names it, from its ``declaration`` in a record (fields may lack)."""
        return str(declared.get("kind"))
