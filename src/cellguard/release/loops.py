"""How a stage's runs are driven: one small interface, ``make_run(scenario) -> Run``, per clock.

``simulated``: today's loop (``cellguard.runner.Run``) on simulated time. ``wall``: the same loop
on the simulated cell paced to the wall clock (the bench stage, until the runtime's real-time loop
against a ``sim-server`` process is on main: register it here as another clock).
"""

from __future__ import annotations

import time
from collections.abc import Callable

from cellguard.runner import Run
from cellguard.scenario import Scenario

PACE_NS = 10_000_000  # the wall-clock loop sleeps to catch up every 10 ms of simulated time [ns]


class WallPacedCell:
    """A simulated cell whose ``step`` never runs ahead of the wall clock (monotonic)."""

    def __init__(self, cell, clock: Callable[[], int] = time.monotonic_ns):
        self._cell, self._clock = cell, clock
        self._t0: tuple[int, int] | None = None  # (simulated, wall) at the first step
        self.lag_ns = 0  # how far the loop fell behind the wall clock at worst [ns]

    def __getattr__(self, name):
        return getattr(self._cell, name)

    def step(self) -> None:
        self._cell.step()
        t = self._cell.t_ns
        if self._t0 is None:
            self._t0 = (t, self._clock())
        if t % PACE_NS:
            return
        ahead = (t - self._t0[0]) - (self._clock() - self._t0[1])
        if ahead > 0:
            time.sleep(ahead * 1e-9)
        else:
            self.lag_ns = max(self.lag_ns, -ahead)


def wall_run(scenario: Scenario) -> Run:
    run = Run(scenario)
    run.cell = WallPacedCell(run.cell)
    return run


CLOCKS: dict[str, Callable[[Scenario], Run]] = {"simulated": Run, "wall": wall_run}
