"""How one recovery attempt ended, written three times: as words in the ``recovery_end`` event's reason, for a
technician; as the same event's fields (``Event.recovery``), recorded when the attempt ends; and as an entry of
the cycle's ``recovery_log``, with the cycle's row at its end. The diagnosis reads the fields, never the words, so
rewording them changes no diagnosis; only a record written before events carried the fields has its words parsed,
for the cycle its run was killed in (no row, so no log).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass

OUTCOMES = ("resumed", "failed", "escalated", "gave_up", "cut_off")
# the words of ``reason`` (the behaviour: any name up to its attempt, as regrasp2 or ReGrasp); numbers of at most 15
# digits a side, so that a crafted one is no int() refuses (over 4,300 digits) and no float() reads as inf
_NUMBER = r"\d{1,15}(?:\.\d{1,15})?"
_PATTERN = re.compile(rf"^(?P<behaviour>.+?): attempt (?P<attempt>\d{{1,15}}) after (?P<trigger>[^,]+), "
                      rf"(?P<duration>{_NUMBER}) s(?:; arrived at contact at (?:(?P<arrival>{_NUMBER}) s|never), "
                      rf"gripper shut at (?P<close>{_NUMBER}) s)?; outcome (?P<outcome>[a-z_]+)$")


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

    def resumed_cell(self) -> bool:
        """Whether the attempt got the cell's task going again: ``resumed`` after a contact. A plan with no contact
        (``rehome``, an ``operator`` hand-over) goes home and its cycle fails by design, though it too ends
        ``resumed`` (its plan ran out with no failed check); counted, it hid recoveries repeated without effect."""
        return self.outcome == "resumed" and self.close_s is not None

    def to_dict(self) -> dict:
        return dict(self.__dict__)

    @classmethod
    def from_dict(cls, entry: object) -> RecoveryOutcome | None:
        """The attempt a ``recovery_log`` entry or an event's ``recovery`` holds (``to_dict``'s fields, read back
        from JSON; one absent is None), its times to the millisecond as its words have them; None for one that is
        not a whole attempt (a damaged or crafted record), which a reader leaves out."""
        if not isinstance(entry, Mapping):
            return None
        text = [entry.get(k) for k in ("behaviour", "trigger", "outcome")]
        times = [entry.get(k) for k in ("duration_s", "arrival_s", "close_s")]
        attempt = entry.get("attempt")
        if (not all(isinstance(v, str) for v in text) or type(attempt) is not int or times[0] is None
                or not all(v is None or _finite(v) for v in times)):
            return None
        return cls(text[0], text[1], attempt, text[2],
                   *(None if v is None else round(float(v), 3) for v in times))._whole()

    @classmethod
    def parse(cls, reason: str) -> RecoveryOutcome | None:
        """The attempt the words of a ``recovery_end`` event describe; None for words that are not an attempt's end.
        Only for a record written before events carried the attempt's fields (see the module's docstring)."""
        m = _PATTERN.match(reason)
        if m is None:
            return None
        number = {k: None if m[k] is None else float(m[k]) for k in ("duration", "arrival", "close")}
        return cls(m["behaviour"], m["trigger"], int(m["attempt"]), m["outcome"], number["duration"],
                   number["arrival"], number["close"])._whole()

    def _whole(self) -> RecoveryOutcome | None:
        """Self, or None for an attempt no run writes: an outcome word not in ``OUTCOMES`` (it read as an attempt
        that fixed nothing), an attempt number below 1, a time below zero."""
        times_ok = self.duration_s >= 0 and all(v is None or 0 <= v for v in (self.arrival_s, self.close_s))
        return self if self.outcome in OUTCOMES and self.attempt >= 1 and times_ok else None


def _finite(value: object) -> bool:
    """A number a float holds: an int too large for one (10**400, from a crafted record) is not."""
    if not isinstance(value, int | float) or isinstance(value, bool):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:
        return False
