"""Re-register the datum from the camera: read where the camera sees the part now, through the
commissioning calibration, and pick it there, beyond the few millimetres a taught program corrects;
then finish the cycle. For a part presented out of place or a fixture that moved.
"""

from typing import Literal

import numpy as np

from cellguard.robot.recovery.base import Plan, Recovery, pick_and_finish


class ReregisterDatum(Recovery):
    do: Literal["reregister_datum"]
    needs = ("reach", "tool_taught", "drop_point", "part_seen")

    def plan(self, cell, q: np.ndarray, attempt: int, origin: np.ndarray) -> Plan:
        return pick_and_finish(cell, q, cell.part_seen(), self.speed_scale)
