"""Watchdog on policy silence: no fresh chunk for ``watchdog_s`` -> a stop of the configured category."""

from __future__ import annotations

from cellguard.control.checks.check import Check, Stop, Tick
from cellguard.control.events import EventKind


class Watchdog(Check):
    """Stop when the last chunk was taken more than ``silence_s`` [s] ago (never before the first chunk)."""

    def __init__(self, silence_s: float, category: int):
        self._silence_ns = silence_s * 1e9
        self._stop = Stop(category, EventKind.WATCHDOG_STOP, f"no fresh chunk for {silence_s * 1e3:.0f} ms")

    def request(self, tick: Tick) -> Stop | None:
        last = tick.last_chunk_ns
        return self._stop if last is not None and tick.t_ns - last > self._silence_ns else None
