"""A new product variant: the part carried gets heavier (or lighter) from a cycle on."""

from typing import ClassVar, Literal

from pydantic import Field

from cellguard.robot.process.base import ProcessChange


class Payload(ProcessChange):
    kind: Literal["payload"]
    grams: float = Field(ge=-1000, le=1000, description="mass added to the part carried [g]")
    hook: ClassVar[str] = "set_payload"

    def apply(self, cell, cycle: int) -> None:
        if cycle >= self.at_cycle:
            cell.set_payload(self.grams * 1e-3)
