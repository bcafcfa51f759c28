"""A category 1 stop the loop asks for (a robot link fault) ends the run with power removed once the arm is still:
the loop ended the cycle as the setpoint came to rest, before the envelope had removed power."""

from __future__ import annotations

from cellguard.control.envelope import STANDSTILL
from cellguard.control.events import EventKind
from cellguard.runtime import Run, run_scenario
from cellguard.scenario import parse_scenario


def test_a_category_1_link_fault_ends_the_run_with_power_removed_at_standstill(tmp_path):
    scenario = parse_scenario({"cell": "arm-pick-place", "seed": 3, "acceptance_cycles": 1, "production_cycles": 0})
    run = Run(scenario)
    cell, safety, faulted = run.cell, run.cell.safety, []

    def fault_once():  # the loop reads the safety inputs once a tick: a link fault 1 s in, mid-motion
        if cell.t_ns >= 1_000_000_000 and not faulted:
            faulted.append(cell.t_ns)
            run.link.fault(cell.t_ns, EventKind.ROBOT_READ_FAILED, "test link fault")
        return safety()

    cell.safety = fault_once
    summary = run_scenario(scenario, tmp_path / "out", run=run)
    assert summary["stopped"].startswith("robot link") and not run.guard.power
    power = next(e for e in summary["events"] if e["kind"] == "power_removed")
    assert power["category"] == 1 and power["asked"] < STANDSTILL
