"""How one recovery attempt ended, written into the ``recovery_end`` event's reason and read back
from it: the record keeps the words a technician reads, and the diagnosis parses the same words.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

OUTCOMES = ("resumed", "failed", "escalated", "gave_up", "cut_off")
# the behaviour: any name up to its attempt (regrasp2, ReGrasp: a name outside [a-z_] hid its every attempt)
_PATTERN = re.compile(r"^(?P<behaviour>.+?): attempt (?P<attempt>\d+) after (?P<trigger>[^,]+), "
                      r"(?P<duration>[\d.]+) s(?:; arrived at contact at (?P<arrival>[\d.]+ s|never), "
                      r"gripper shut at (?P<close>[\d.]+) s)?; outcome (?P<outcome>[a-z_]+)$")


@dataclass(frozen=True)
class RecoveryOutcome:
    """One attempt: ``duration_s`` [s]; ``arrival_s`` [s] after its start the arm reached its contact pose
    (None: never), ``close_s`` [s] when the gripper was told to shut (None: a plan without contact)."""

    behaviour: str
    trigger: str
    attempt: int
    outcome: str
    duration_s: float
    arrival_s: float | None = None
    close_s: float | None = None

    def reason(self) -> str:
        words = f"{self.behaviour}: attempt {self.attempt} after {self.trigger}, {self.duration_s:.3f} s"
        if self.close_s is not None:
            arrived = f"{self.arrival_s:.3f} s" if self.arrival_s is not None else "never"
            words += f"; arrived at contact at {arrived}, gripper shut at {self.close_s:.3f} s"
        return f"{words}; outcome {self.outcome}"

    def to_dict(self) -> dict:
        return dict(self.__dict__)

    @classmethod
    def parse(cls, reason: str) -> RecoveryOutcome | None:
        """The attempt a ``recovery_end`` reason describes; None for one that is not an attempt's end."""
        m = _PATTERN.match(reason)
        if m is None:
            return None
        arrival = m["arrival"]
        return cls(m["behaviour"], m["trigger"], int(m["attempt"]), m["outcome"], float(m["duration"]),
                   float(arrival[:-2]) if arrival and arrival != "never" else None,
                   float(m["close"]) if m["close"] else None)
