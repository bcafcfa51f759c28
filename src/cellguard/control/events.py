"""Events: every intervention of the guard layer, with what was asked, what was sent and why.

``EventKind`` is the one list of event kinds, each with whether it is routine (normal
bookkeeping: no full-rate record window, not a safety event in a diagnosis) and the stop
category it carries, if it is a stop. The values are the strings written into records and the
``diagnose --json`` contract: add kinds, never rename them. ``EventKind`` is a ``str``, so a
kind compares equal to its string and serialises as it.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum


class EventKind(StrEnum):
    """What happened; ``routine`` and ``category`` (IEC 60204-1, None: not a stop of its own) per kind."""

    def __new__(cls, value: str, routine: bool = False, category: int | None = None):
        member = str.__new__(cls, value)
        member._value_ = value
        member.routine, member.category = routine, category
        return member

    # executor: chunks in
    CHUNK_REJECTED = "chunk_rejected"
    CHUNK_STALE = "chunk_stale"
    CHUNK_STEPS_DROPPED = "chunk_steps_dropped", True
    # envelope: stops (category None: the category is the request's, e.g. the safety input's)
    PROTECTIVE_STOP = "protective_stop"
    REFERENCE_INVALID = "reference_invalid", False, 2
    EFFORT_LIMIT = "effort_limit"
    EFFORT_STOP = "effort_stop", False, 2
    WATCHDOG_STOP = "watchdog_stop"
    UNCERTAINTY_HOLD = "uncertainty_hold", False, 2
    WORKSPACE_STOP = "workspace_stop", False, 2
    POWER_REMOVED = "power_removed"
    RESUME = "resume"
    # envelope: limits and lasting conditions
    LIMIT_INTERVENTION = "limit_intervention"
    LIMIT_BRAKE = "limit_brake"
    TRACKER_FAILED = "tracker_failed"
    REDUCED_SPEED_INPUT = "reduced_speed_input"
    REDUCED_SPEED_INPUT_CLEARED = "reduced_speed_input_cleared"
    UNCERTAINTY_GATE = "uncertainty_gate"
    UNCERTAINTY_GATE_CLEARED = "uncertainty_gate_cleared"
    # the loop
    RESET = "reset"
    INFERENCE_FAILED = "inference_failed"
    RECORD_FAILED = "record_failed", False, 2


ROUTINE_EVENTS = frozenset(k.value for k in EventKind if k.routine)  # kinds that are normal bookkeeping


@dataclass(frozen=True)
class Event:
    """One intervention or incident. ``category`` is the IEC 60204-1 stop category, if a stop."""

    t_ns: int
    kind: str  # an EventKind (a str); a reader may meet kinds this version does not know
    reason: str
    joint: str | None = None
    asked: float | None = None
    sent: float | None = None
    category: int | None = None

    def to_dict(self) -> dict:
        return {k: (str(v) if k == "kind" else v) for k, v in self.__dict__.items() if v is not None}
