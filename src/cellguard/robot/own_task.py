"""A simulated cell running its own task, as a cell behind a robot interface does.

Behind `cellguard sim-server` and behind the LeRobot plugin's simulated SO-101 nobody calls
``begin_cycle``: when a cycle is over the next part arrives at once, and the cell raises the
digital input ``cycle_done`` for ``PULSE_S`` (a PLC's part-done signal, which a loop on hardware
reads as its cycle source). Injected faults act on the world as the cycles pass (simulation only).
A new client (``new_session``) finds a cycle under way that was the last client's (a run stopped
mid-cycle, the arm away from home): it ends unannounced, and the next part comes (the new run's
approach brought the arm home and its first cycle read a success it never worked for).
"""

from __future__ import annotations

from collections.abc import Sequence

from cellguard.robot.world_changes import apply_world_changes

PULSE_NS = 50_000_000  # cycle_done stays high this long [ns]


class OwnTask:
    """The cell's task, advanced by ``poll`` after each step; ``cycle_done(t_ns)`` is the input."""

    def __init__(self, cell, faults: Sequence = ()):
        self.cell, self.faults = cell, tuple(faults)
        self.cycle = 0
        self._pulse_until = None
        self._void = False  # the cycle under way is a former client's: it ends without the pulse
        self._begin()

    def poll(self, t_ns: int) -> bool:
        """End a finished cycle and present the next part; True when a cycle ended now."""
        if not self.cell.cycle_finished():
            return False
        self.cell.end_cycle()
        self.cycle += 1
        self._begin()
        void, self._void = self._void, False
        if void:
            return False
        self._pulse_until = t_ns + PULSE_NS
        return True

    def new_session(self) -> None:
        """A new client takes the cell: a cycle already under way is not its own."""
        self._void = self.cell.cycle_under_way()
        self._pulse_until = None

    def cycle_done(self, t_ns: int) -> bool:
        return self._pulse_until is not None and t_ns < self._pulse_until

    def _begin(self) -> None:
        apply_world_changes(self.cell, self.faults, self.cycle)
        self.cell.begin_cycle(self.cycle)
