"""The certified safety controller's inputs: a protective stop of its category, and reduced speed."""

from __future__ import annotations

from cellguard.control.checks.check import Check, SpeedCap, Stop, Tick
from cellguard.control.events import EventKind

REDUCED_SCALE_WITHOUT_TOOL = 0.25  # playback speed in reduced mode when no tool model gives the tool speed
ASKED_BY_LOOP = "stop asked by the loop: "  # a protective stop's reason when the loop asked (its cause is its own event)
RECOVERY_HOLD = "a recovery's hand-over hold"  # what the loop asks while a recovery takes over: no event of its own


class ProtectiveStopInput(Check):
    """The controller's protective-stop input, obeyed at the category it asks for."""

    def __init__(self):
        self._stops = {c: Stop(c, EventKind.PROTECTIVE_STOP, "safety controller protective stop input")
                       for c in (0, 1, 2)}

    def request(self, tick: Tick) -> Stop | None:
        safety = tick.safety
        if safety.stop is None:
            return None
        if safety.asked_by is not None:  # the loop's own stop: the record must not blame the controller
            return Stop(safety.stop, EventKind.PROTECTIVE_STOP, ASKED_BY_LOOP + safety.asked_by)
        return self._stops[safety.stop]


class ReducedSpeedInput(Check):
    """The controller's reduced-speed input: the tool at most ``reduced_speed`` [m/s] (ISO 10218-1)."""

    def __init__(self, reduced_speed: float):
        self._cap = SpeedCap(reduced_speed, REDUCED_SCALE_WITHOUT_TOOL, EventKind.REDUCED_SPEED_INPUT,
                             "safety controller reduced-speed input")

    def request(self, tick: Tick) -> SpeedCap | None:
        return self._cap if tick.safety.reduced_speed else None
