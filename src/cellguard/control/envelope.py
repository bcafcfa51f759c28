"""Envelope: the last software check between the reference and the robot.

Inside the envelope it passes the reference through unchanged (no filter, no delay). This first
version enforces the profile's position limits; clamps raise one event per excursion per joint.
"""

from __future__ import annotations

import numpy as np

from cellguard.control.events import Event
from cellguard.embodiment import Profile


class Envelope:
    """Position limits from the profile; returns the setpoint and the events it raised."""

    def __init__(self, profile: Profile):
        self.profile = profile
        self._lo, self._hi = profile.q_min, profile.q_max
        self._clamping = np.zeros(profile.dof, dtype=bool)

    def apply(self, t_ns: int, reference: np.ndarray) -> tuple[np.ndarray, list[Event]]:
        setpoint = np.clip(reference, self._lo, self._hi)
        clamped = setpoint != reference
        events: list[Event] = []
        if clamped.any() or self._clamping.any():
            for i in np.flatnonzero(clamped & ~self._clamping):
                events.append(Event(t_ns, "position_clamp", "reference outside the position limit",
                                    joint=self.profile.joint_names[i], asked=float(reference[i]),
                                    sent=float(setpoint[i])))
            self._clamping = clamped
        return setpoint, events
