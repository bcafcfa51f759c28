"""The protocol every envelope check implements: read this tick, answer a stop or a limit request, or None.

A check is one idea (the watchdog, the effort limit, the workspace box, ...) in its own module.
The envelope calls ``request(tick)`` on each check of a phase once per servo tick and combines
the answers in a short loop: the strictest stop wins (lowest IEC 60204-1 category), the lowest
tool-speed cap wins. The joint limits (position with look-ahead, velocity, acceleration, jerk)
are the tracker's: they shape the setpoint rather than request anything.
"""

from __future__ import annotations

from dataclasses import dataclass

from cellguard.control.events import Event, EventKind
from cellguard.robot.protocol import SafetyInputs


class Tick:
    """What the checks read this tick; one object per envelope, overwritten every tick (no allocation).

    ``reference``: the executor's sample (D,); ``finite``: whether it is all finite; ``state``:
    the measured robot state or None; ``last_chunk_ns``: when the last chunk was taken;
    ``uncertainty``: the policy's, at this playback time; ``stop_kind``: the stop in force when the tick
    began, if any; after tracking, the tool point ``tip`` (3,) [m] of the setpoint.
    """

    __slots__ = ("t_ns", "reference", "finite", "state", "safety", "last_chunk_ns", "uncertainty", "stop_kind", "tip")

    def __init__(self):
        self.t_ns, self.reference, self.finite, self.state = 0, None, True, None
        self.safety, self.last_chunk_ns, self.uncertainty, self.stop_kind = SafetyInputs(), None, 0.0, None
        self.tip: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class Stop:
    """Stop of ``category`` now, reported as ``kind`` with ``reason``; ``detail`` is reported before it."""

    category: int
    kind: EventKind
    reason: str
    detail: Event | None = None


@dataclass(frozen=True)
class SpeedCap:
    """Tool speed at most ``cap`` [m/s] (playback ``scale_without_tool`` where no tool model gives the
    tool speed); ``condition`` names a lasting condition reported when it starts and when it clears."""

    cap: float
    scale_without_tool: float = 1.0
    condition: EventKind | None = None
    reason: str = ""


class Check:
    """One check of the envelope. ``request`` once per tick; ``reset`` on an operator reset."""

    def request(self, tick: Tick) -> Stop | SpeedCap | None:
        raise NotImplementedError

    def reset(self) -> None:
        """Forget what this check counted (default: nothing to forget)."""
