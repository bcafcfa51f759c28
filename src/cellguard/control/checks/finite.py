"""A reference that is not finite (NaN, inf) is never sent: category 2 stop while it lasts."""

from __future__ import annotations

from cellguard.control.checks.check import Check, Stop, Tick
from cellguard.control.events import EventKind

STOP = Stop(2, EventKind.REFERENCE_INVALID, "non-finite reference")


class FiniteReference(Check):
    """Stop on a non-finite reference sample (the executor refuses such chunks; this is the second line)."""

    def request(self, tick: Tick) -> Stop | None:
        return None if tick.finite else STOP
