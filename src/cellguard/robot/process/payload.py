"""A new product variant: the part carried gets heavier (or lighter) from a cycle on."""

from collections.abc import Mapping
from typing import ClassVar, Literal

from pydantic import Field

from cellguard.robot.process.base import ProcessChange


class Payload(ProcessChange):
    kind: Literal["payload"]
    grams: float = Field(ge=-1000, le=1000, description="mass added to the part carried [g]")
    hook: ClassVar[str] = "set_payload"
    diagnosis: ClassVar[str] = "rebase"

    @classmethod
    def describe(cls, declared: Mapping) -> str:
        grams = declared.get("grams")
        return f"payload {grams:+g} g" if isinstance(grams, (int, float)) else "payload change"

    def apply(self, cell, cycle: int) -> None:
        if cycle >= self.at_cycle:
            cell.set_payload(self.grams * 1e-3)
