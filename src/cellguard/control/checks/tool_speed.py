"""Tool-speed cap in normal operation [m/s]: the playback slows before a fast stretch of the chunk."""

from __future__ import annotations

from cellguard.control.checks.check import Check, SpeedCap, Tick


class ToolSpeedCap(Check):
    """The tool point at most ``cap`` [m/s]; without a tool model the joint limits alone apply."""

    def __init__(self, cap: float):
        self._cap = SpeedCap(cap)

    def request(self, tick: Tick) -> SpeedCap:
        return self._cap
