"""Uncertainty gate: a policy unsure of its chunk (uncertainty above a threshold) runs slow or holds."""

from __future__ import annotations

from cellguard.control.checks.check import Check, SpeedCap, Stop, Tick
from cellguard.control.checks.safety_input import REDUCED_SCALE_WITHOUT_TOOL
from cellguard.control.events import EventKind


class UncertaintyHold(Check):
    """Category 2 stop while the uncertainty is above ``threshold``; tracking resumes when it clears."""

    def __init__(self, threshold: float):
        self._threshold = threshold
        self._stop = Stop(2, EventKind.UNCERTAINTY_HOLD, f"policy uncertainty above {threshold:.3g}")

    def request(self, tick: Tick) -> Stop | None:
        return self._stop if tick.uncertainty > self._threshold else None


class UncertaintyGate(Check):
    """Reduced speed (``reduced_speed`` [m/s]) while the uncertainty is above ``threshold``."""

    def __init__(self, threshold: float, reduced_speed: float):
        self._threshold = threshold
        self._cap = SpeedCap(reduced_speed, REDUCED_SCALE_WITHOUT_TOOL, EventKind.UNCERTAINTY_GATE,
                             f"policy uncertainty above {threshold:.3g}")

    def request(self, tick: Tick) -> SpeedCap | None:
        return self._cap if tick.uncertainty > self._threshold else None
