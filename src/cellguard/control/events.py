"""Events: every intervention of the guard layer, with what was asked, what was sent and why."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Event:
    """One intervention or incident. ``category`` is the IEC 60204-1 stop category, if a stop."""

    t_ns: int
    kind: str  # e.g. "chunk_rejected", "limit_intervention", "watchdog_stop"
    reason: str
    joint: str | None = None
    asked: float | None = None
    sent: float | None = None
    category: int | None = None

    def to_dict(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if v is not None}
