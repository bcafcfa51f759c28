"""The robot link as the loop uses it: reads and writes that never raise, watched every tick.

A read that raises, times out, returns a stale stamp (a dead bus reads as a frozen but healthy
robot) or one from the future (a clock that jumped), or a state that is not finite, a write that
fails, and more lost packets than the budget each raise one named event and ask the guard for the
scenario's stop category; a state that is not finite is never used (the last good one stands in). A state stamped
out of date and one standing in after a failed read are handed over as ``StaleState``: the guard reads no standstill
from them (a category 1 stop waits for a fresh one); one stamped ahead is a fault, but its data is fresh.
A setpoint that is not finite never reaches the robot: the last finite one is sent again and the
refusal is an event.
"""

from __future__ import annotations

import math

import numpy as np

from cellguard.control.envelope import StaleState
from cellguard.control.events import Event, EventKind
from cellguard.robot.protocol import RobotLinkError


class RobotLink:
    """Wraps a Robot's ``read``/``write``; ``stop`` is the stop category asked for, or None."""

    def __init__(self, robot, events: list, stop_category: int, stale_ns: int | None = None,
                 drop_budget: int | None = None):
        self.robot, self.events, self.category = robot, events, int(stop_category)
        self.stale_ns = stale_ns
        self.drop_budget = drop_budget if hasattr(robot, "dropped") else None  # only a bridge counts lost packets
        self.stop: int | None = None
        self.reason: str | None = None  # the first fault, "kind: why"
        self.lost = False  # no state at all any more: the loop cannot command the robot
        self.refused = 0  # non-finite setpoints never sent
        self.state = None  # the last good state, once read
        self.last_sent: np.ndarray | None = None  # the last setpoint sent (before any: the first measured pose)
        self._raised: set[str] = set()

    def read(self, t_ns: int):
        """The measured state; after a failure the last good one, stale (and a stop request)."""
        try:
            state = self.robot.read()
        except RobotLinkError as exc:
            self.fault(t_ns, EventKind(exc.kind), str(exc))  # the bridge names one of the link kinds
            self.lost = self.lost or exc.lost
            return self._stand_in()
        except Exception as exc:  # noqa: BLE001 - a bridge bug must stop the robot, not kill the loop
            self.fault(t_ns, EventKind.ROBOT_READ_FAILED, f"{type(exc).__name__}: {exc}")
            return self._stand_in()
        q, qd, effort = state.q, state.qd, state.effort
        with np.errstate(over="ignore", invalid="ignore"):  # refused below by name: no numpy warning on top
            squares = q.dot(q) + qd.dot(qd) + effort.dot(effort)
        if not math.isfinite(squares):  # NaN, inf or absurd (a square beyond the float range) anywhere
            self.fault(t_ns, EventKind.ROBOT_READ_FAILED, "the robot reported a position, velocity or effort that "
                       "is not finite; the last good state stands in")
            return self._stand_in()
        if self.stale_ns is not None and abs(t_ns - state.t_ns) > self.stale_ns:
            age = (t_ns - state.t_ns) * 1e-6
            self.fault(t_ns, EventKind.ROBOT_STATE_STALE, (f"state stamp {age:.1f} ms old" if age > 0 else
                        f"state stamp {-age:.1f} ms ahead of the loop's clock") +
                       f" (limit {self.stale_ns * 1e-6:.0f} ms)")
            if age > 0:  # one stamped ahead (a clock that jumped, a bridge stamping after its read) is a fault, but
                state = StaleState.of(state)  # its data is fresh: a category 1 stop may read standstill from it
        if self.drop_budget is not None and self.robot.dropped > self.drop_budget:
            self.fault(t_ns, EventKind.ROBOT_PACKETS_DROPPED, f"{self.robot.dropped} packets lost "
                        f"(budget {self.drop_budget})")
        self.state = state
        if self.last_sent is None:
            self.last_sent = np.array(state.q, dtype=np.float64)
        return state

    def _stand_in(self):
        """The last good state, standing in for one not read: stale from now on (None before any)."""
        if self.state is not None and not isinstance(self.state, StaleState):
            self.state = StaleState.of(self.state)
        return self.state

    def write(self, t_ns: int, setpoint: np.ndarray) -> np.ndarray:
        """Send ``setpoint`` if every value is finite, else the last finite one; return what was sent."""
        with np.errstate(over="ignore", invalid="ignore"):
            square = setpoint.dot(setpoint)
        if not math.isfinite(square):  # NaN or inf anywhere (or an absurd 1e154) -> not finite
            self.refused += 1
            self._event(t_ns, "setpoint_not_finite", "a non-finite setpoint was not sent; the last one is held")
            setpoint = self.last_sent
        try:
            sent = self.robot.write(setpoint)
        except RobotLinkError as exc:
            self.fault(t_ns, EventKind(exc.kind), str(exc))  # the bridge names one of the link kinds
            self.lost = self.lost or exc.lost
            return self.last_sent
        except Exception as exc:  # noqa: BLE001
            self.fault(t_ns, EventKind.ROBOT_WRITE_FAILED, f"{type(exc).__name__}: {exc}")
            return self.last_sent
        self.last_sent = setpoint
        return sent

    def power_off(self, t_ns: int) -> None:
        """Drive power off after a category 0/1 stop; a robot that cannot be switched off (a hung bus, a server
        that cannot be sent to) is a write fault, never an exception on the servo path (the cell's safety
        controller must then do it), and always its own event: a write fault before it hid it."""
        try:
            self.robot.set_power(False)
        except Exception as exc:  # noqa: BLE001
            self.fault(t_ns, EventKind.ROBOT_WRITE_FAILED, f"drive power-off not confirmed: {type(exc).__name__}: "
                       f"{exc}", once=False)

    def fault(self, t_ns: int, kind: str, reason: str, once: bool = True) -> None:
        """A link fault: one event of its kind (``once``), and the stop category asked from the guard from now on."""
        if self._event(t_ns, kind, reason, self.category, once):
            self.reason = self.reason or f"{kind}: {reason}"
            self.stop = self.category if self.stop is None else min(self.stop, self.category)

    def _event(self, t_ns: int, kind: str, reason: str, category: int | None = None, once: bool = True) -> bool:
        """One event per kind and run (a lasting condition is not repeated every tick), unless not ``once``."""
        if once and kind in self._raised:
            return False
        self._raised.add(kind)
        self.events.append(Event(t_ns, kind, reason, category=category))
        return True
