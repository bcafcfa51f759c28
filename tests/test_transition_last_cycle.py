"""A category 0 or 1 stop in the last cycle (or during its approach) ends the run stopped: power is off, no
operator reset follows and the robot is not home. The retreat returned silently with power off and the run ended
clean, exit 0, summary.json with no ``stopped``."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from cellguard.control.settings import build_guard
from cellguard.robot.protocol import SafetyInputs
from cellguard.runtime import Run
from cellguard.scenario import parse_scenario

ONE_CYCLE = {"cell": "arm-pick-place", "seed": 3, "acceptance_cycles": 1, "production_cycles": 0,
             "cycle": {"source": "time", "seconds": 2.5}}


def _run(pulse: tuple[float, float, int], away: np.ndarray | None = None) -> Run:
    """One cycle with the safety controller's stop input of category ``pulse[2]`` from ``pulse[0]`` to ``pulse[1]``
    [s], the arm starting ``away`` from home (an approach is played)."""
    run = Run(parse_scenario(ONE_CYCLE))
    cell = run.cell
    if away is not None:
        q = cell.q_home + away
        cell.data.qpos[cell.drives.qadr] = q
        cell.write(q)
        mujoco.mj_forward(cell.model, cell.data)
        run.guard = build_guard(cell, run.scenario.guard)
    begin, end, category = pulse
    cell.safety = lambda: SafetyInputs(stop=category if begin <= cell.t_ns * 1e-9 < end else None)
    try:
        run.run_cycles()
    finally:
        run.close()
    return run


@pytest.mark.parametrize("category", [0, 1])
def test_a_category_0_or_1_stop_in_the_last_cycle_ends_the_run_stopped(category):
    run = _run((1.0, 1.1, category))
    kinds = [e.kind for e in run.events]
    assert "power_removed" in kinds and "retreat_begin" not in kinds and not run.guard.power
    assert run.stopped.startswith(f"power removed by a category {category} stop") and "reset the cell" in run.stopped


def test_a_category_0_stop_during_the_last_cycles_approach_ends_the_run_stopped():
    run = _run((0.1, 0.15, 0), away=np.array([0.6, 0.3, -0.4, 0.0, 0.0, 0.0]))
    kinds = [e.kind for e in run.events]
    assert kinds.index("approach_begin") < kinds.index("approach_aborted") < kinds.index("power_removed")
    assert run.stopped.startswith("power removed by a category 0 stop")
