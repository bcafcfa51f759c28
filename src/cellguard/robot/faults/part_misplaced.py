"""Parts presented out of place now and then (a feeder that mis-seats one part in five): the part
sits off its fixture datum on some cycles; the camera sees it truly."""

from typing import Literal

from cellguard.robot.faults.intermittent import IntermittentOffset


class PartMisplaced(IntermittentOffset):
    kind: Literal["part_misplaced"]
    setter = "set_part_offset"
