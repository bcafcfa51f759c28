"""How one recovery attempt ended, written twice: as words in the ``recovery_end`` event's reason, for a
technician, and as fields in the cycle's ``recovery_log``, which the diagnosis reads. It never parses the words,
so rewording them changes no diagnosis.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

OUTCOMES = ("resumed", "failed", "escalated", "gave_up", "cut_off")


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
    def from_dict(cls, entry: object) -> RecoveryOutcome | None:
        """The attempt a ``recovery_log`` entry holds (``to_dict``'s fields, read back from JSON); None for one
        that is not a whole attempt (a damaged or crafted record), which a reader leaves out."""
        if not isinstance(entry, Mapping):
            return None
        text = [entry.get(k) for k in ("behaviour", "trigger", "outcome")]
        times = [entry.get(k) for k in ("duration_s", "arrival_s", "close_s")]
        attempt = entry.get("attempt")
        if (not all(isinstance(v, str) for v in text) or type(attempt) is not int or times[0] is None
                or not all(v is None or _finite(v) for v in times)):
            return None
        return cls(text[0], text[1], attempt, text[2], *(None if v is None else float(v) for v in times))


def _finite(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
