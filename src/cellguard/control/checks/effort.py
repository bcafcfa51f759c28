"""Effort limit: measured |effort| above a fraction of the joint's limit for a while -> category 2 stop.

Collisions and jams show as effort; a short peak (a grasp, a bump) is not one, hence the hold time.
"""

from __future__ import annotations

from cellguard.control.checks.check import Check, Stop, Tick
from cellguard.control.events import Event, EventKind
from cellguard.embodiment import Profile


class EffortLimit(Check):
    """Stop when a joint's |effort| stays above ``fraction`` of its limit for ``hold_s`` [s], in whole servo
    samples (at least 2); the event says the hold that was served."""

    def __init__(self, profile: Profile, fraction: float, hold_s: float, dt_ns: int):
        self._names, self._limit = profile.joint_names, profile.array("effort").tolist()
        self._max = (profile.array("effort") * fraction).tolist()
        self._ticks = [0] * profile.dof  # ticks each joint has been above (plain ints: cheaper per tick than numpy)
        self._hold = _hold_samples(hold_s, dt_ns)
        self._reason = (f"effort above {fraction:.0%} of the limit for {_ms(self._hold * dt_ns)} ms "
                        f"({self._hold} samples of {_ms(dt_ns)} ms)")

    def request(self, tick: Tick) -> Stop | None:
        state = tick.state
        if state is None:
            return None
        ticks = self._ticks = [n + 1 if abs(e) > m else 0
                               for n, e, m in zip(self._ticks, state.effort.tolist(), self._max)]
        longest = max(ticks)
        if tick.stop_kind == EventKind.EFFORT_STOP or longest < self._hold:
            return None
        j = ticks.index(longest)
        self.reset()
        detail = Event(tick.t_ns, EventKind.EFFORT_LIMIT, self._reason, joint=self._names[j],
                       asked=float(state.effort[j]), sent=self._limit[j])
        return Stop(2, EventKind.EFFORT_STOP, "effort limit", detail)

    def reset(self) -> None:
        self._ticks = [0] * len(self._ticks)


def _hold_samples(hold_s: float, dt_ns: int) -> int:
    """Samples over the limit that make a stop: never less than ``hold_s`` (rounding to the nearest sample
    made the 50 ms hold one sample at 20 Hz and below, so one peak stopped the robot), and at least 2."""
    return max(2, -(-round(hold_s * 1e9) // dt_ns))


def _ms(ns: int) -> str:
    return f"{round(ns * 1e-6, 1):g}"
