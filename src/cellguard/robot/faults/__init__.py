"""Fault kinds for simulated cells: every module of this package that defines one (a ``Fault`` with its ``kind``)
is found here, so a new kind is one new file; ``FAULTS`` maps kind to class."""

from typing import Annotated, Union

from pydantic import Field

from cellguard.robot.faults.base import Fault
from cellguard.robot.kinds import discover

# the order scenario errors have listed the known kinds in; kinds added later follow by name
_LISTED = ("fixture_shift", "friction_growth", "servo_gain", "camera_shift", "tool_slip", "policy_latency",
           "policy_nan", "friction_step", "intermittent_slip", "part_misplaced", "late_recovery")
FAULTS: dict[str, type[Fault]] = discover(__name__, __path__, Fault, "fault kind", first=_LISTED)
AnyFault = Annotated[Union[tuple(FAULTS.values())], Field(discriminator="kind")]  # noqa: UP007

__all__ = ["FAULTS", "AnyFault", "Fault"]
