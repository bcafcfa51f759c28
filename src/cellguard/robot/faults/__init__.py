"""Fault kinds for simulated cells, registered in one place: ``FAULTS`` maps kind to class."""

from typing import Annotated, Union

from pydantic import Field

from cellguard.robot.faults.base import Fault
from cellguard.robot.faults.camera_shift import CameraShift
from cellguard.robot.faults.fixture_shift import FixtureShift
from cellguard.robot.faults.friction_growth import FrictionGrowth
from cellguard.robot.faults.friction_step import FrictionStep
from cellguard.robot.faults.intermittent_slip import IntermittentSlip
from cellguard.robot.faults.late_recovery import LateRecovery
from cellguard.robot.faults.part_misplaced import PartMisplaced
from cellguard.robot.faults.policy_latency import PolicyLatency
from cellguard.robot.faults.policy_nan import PolicyNaN
from cellguard.robot.faults.servo_gain import ServoGain
from cellguard.robot.faults.tool_slip import ToolSlip

_KINDS = (FixtureShift, FrictionGrowth, ServoGain, CameraShift, ToolSlip, PolicyLatency, PolicyNaN, FrictionStep,
          IntermittentSlip, PartMisplaced, LateRecovery)
FAULTS: dict[str, type[Fault]] = {k.model_fields["kind"].annotation.__args__[0]: k for k in _KINDS}
AnyFault = Annotated[Union[_KINDS], Field(discriminator="kind")]  # noqa: UP007

__all__ = ["FAULTS", "AnyFault", "Fault"]
