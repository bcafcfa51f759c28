"""A gripper that slips now and then: on some cycles the part sits off the tool point at grasp."""

from typing import Literal

from cellguard.robot.faults.intermittent import IntermittentOffset


class IntermittentSlip(IntermittentOffset):
    kind: Literal["intermittent_slip"]
    setter = "set_tool_offset"
