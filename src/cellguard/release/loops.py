"""How a stage's runs are driven: one small interface, ``make_run(scenario) -> Run``, per clock.

``simulated``: the runtime loop on simulated time. ``wall``: the same loop on the wall clock
(the bench stage): a simulated cell paced in real time, or a robot bridge such as ``sim-server``
when the stage's scenario names one in ``robot:``.
"""

from __future__ import annotations

from collections.abc import Callable

from cellguard.runtime import Run
from cellguard.scenario import Scenario


def wall_run(scenario: Scenario) -> Run:
    return Run(scenario, realtime=True)


CLOCKS: dict[str, Callable[[Scenario], Run]] = {"simulated": Run, "wall": wall_run}
