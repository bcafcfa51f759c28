"""Hidden physics of a simulated cell: the ground truth a calibration must find.

A ``Physics`` changes a built cell's ``MjModel`` away from the nominal MJCF (dry friction and
armature as multiples of the commissioned values, a payload on a body, a command delay in the
drives) after the cell is built, so nothing that reads the model file or the record sees it.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import mujoco
import numpy as np


@dataclass(frozen=True)
class Physics:
    """``friction`` {joint: factor}; ``armature`` factor on every profiled joint; ``payload_kg`` added
    at ``payload_body``'s centre of mass; ``delay_s`` between a setpoint taken and it acting."""

    friction: dict[str, float] = field(default_factory=dict)
    armature: float = 1.0
    payload_kg: float = 0.0
    payload_body: str = "tool"
    delay_s: float = 0.0

    def apply(self, cell) -> None:
        """Change ``cell``'s model (and drives, for the delay) in place; once, right after it is built."""
        m, drives = cell.model, cell.drives
        for joint, factor in self.friction.items():
            drives.set_friction_scale(joint, factor)
        m.dof_armature[drives.dadr] *= self.armature
        if self.payload_kg:
            body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, self.payload_body)
            m.body_mass[body] += self.payload_kg  # at the body's centre of mass; no mj_setConst: the
            # constraint softness it rescales is commissioning data, not physics
        ticks = round(self.delay_s * 1e9 / cell.dt_ns)
        if ticks:
            _delay_drives(drives, ticks)


def _delay_drives(drives, ticks: int) -> None:
    """The drives act on each setpoint ``ticks`` servo periods after taking it; they report it as taken."""
    write = drives.write
    queue: deque = deque()

    def delayed(setpoint: np.ndarray) -> np.ndarray:
        taken = np.array(setpoint, dtype=np.float64)
        queue.append(taken)
        write(queue[0])  # the setpoint taken ``ticks`` periods ago (the first one until then)
        if len(queue) > ticks:
            queue.popleft()
        return taken

    drives.write = delayed
