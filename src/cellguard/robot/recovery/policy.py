"""The scenario's ``recovery:`` section: which failed check starts which behaviour, and the limits.

Checked before anything runs: a behaviour named twice, two behaviours on one trigger (only the
first ever ran), a behaviour nothing starts (no trigger, no escalation to it), an escalation to a
behaviour not declared, a trigger the cell does not report, a behaviour the cell cannot run, and
a loop of escalations with no per-cycle limit each raise ``ScenarioError`` naming the key.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pydantic import BaseModel, ConfigDict, Field, model_validator
from pydantic_core import PydanticCustomError

from cellguard.errors import ScenarioError

if TYPE_CHECKING:
    from cellguard.robot.recovery import AnyRecovery


class RecoveryPolicy(BaseModel):
    """``behaviours``: the declared behaviours; ``max_per_cycle``: recoveries allowed in one cycle
    (required when escalations loop back)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    behaviours: list[AnyRecovery] = Field(min_length=1, max_length=50)
    max_per_cycle: int | None = Field(default=None, ge=1, le=100, description="recoveries allowed in one cycle")

    @model_validator(mode="after")
    def _consistent(self):
        names = [b.do for b in self.behaviours]
        triggers = [b.trigger for b in self.behaviours]
        for i, b in enumerate(self.behaviours):
            if names.count(b.do) > 1:
                raise _bad(f"behaviours[{i}].do: {b.do!r} is declared twice")
            if b.then is not None and b.then not in names:
                raise _bad(f"behaviours[{i}].then: {b.then!r} is not a declared behaviour; "
                                 f"declared: {', '.join(names)}")
            if b.trigger is not None and triggers.index(b.trigger) < i:
                raise _bad(f"behaviours[{i}].trigger: {b.trigger!r} already starts "
                           f"{names[triggers.index(b.trigger)]!r}; escalate with then: instead")
        if self.max_per_cycle is None:
            for i, b in enumerate(self.behaviours):
                chain, step = [b.do], b.then
                while step is not None and step not in chain:
                    chain.append(step)
                    step = self.behaviour(step).then
                if step is not None:
                    raise _bad(f"behaviours[{i}].then: the escalations loop ({' -> '.join(chain + [step])}) "
                                     "without a limit; set recovery.max_per_cycle (1..100)")
        reached = {b.do for b in self.behaviours if b.trigger is not None}
        while new := {b.then for b in self.behaviours if b.do in reached and b.then not in reached} - {None}:
            reached |= new
        for i, b in enumerate(self.behaviours):
            if b.do not in reached:
                raise _bad(f"behaviours[{i}]: {b.do!r} has no trigger and no triggered behaviour escalates to it, "
                           "so it never runs")
        return self

    def behaviour(self, name: str):
        return next(b for b in self.behaviours if b.do == name)

    def for_trigger(self, trigger: str):
        """The behaviour the failed check ``trigger`` starts, or None."""
        return next((b for b in self.behaviours if b.trigger == trigger), None)

    def check_against(self, cell) -> None:
        """Refuse behaviours the cell cannot run and triggers it does not report (a robot behind a bridge is refused
        with the scenario: ``scenario._check_bridge``)."""
        checks = getattr(cell, "failure_checks", ())
        for i, b in enumerate(self.behaviours):
            missing = [n for n in b.needs if not callable(getattr(cell, n, None))]
            if missing:
                raise ScenarioError(f"recovery.behaviours[{i}].do: {b.do!r} cannot run on {cell.name!r}; it needs "
                                    f"a cell that can {', '.join(missing)} (pick-place cells can)")
            if b.trigger is not None and b.trigger not in checks:
                raise ScenarioError(f"recovery.behaviours[{i}].trigger: {cell.name!r} does not report {b.trigger!r}; it "
                                    f"reports: {', '.join(checks) or 'no failed checks'}")


def _bad(message: str) -> PydanticCustomError:
    return PydanticCustomError("recovery", message)
