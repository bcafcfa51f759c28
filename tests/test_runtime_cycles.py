"""Cycle sources: where a cycle ends on a simulated cell and on hardware."""

from __future__ import annotations

import numpy as np
import pytest

from cellguard.errors import ScenarioError
from cellguard.robot.registry import make_cell
from cellguard.robot.state import State
from cellguard.runtime import Run
from cellguard.runtime.cycles import DigitalInput, FixedTime, HomeReturn, PolicyEpisodeEnd, make_cycle_source
from cellguard.runtime.history import CycleWindow, EventLog
from cellguard.control.events import Event
from cellguard.scenario import CycleSettings, parse_scenario


def _state(t_s, q, qd=0.0):
    q = np.asarray(q, dtype=np.float64)
    return State(round(t_s * 1e9), q, np.full(q.shape, qd), np.zeros(q.shape), np.zeros(q.shape))


def test_home_return_needs_leaving_home_first_then_arriving_slow():
    home = np.zeros(2)
    source = HomeReturn(home, tolerance=0.01)
    source.begin(0, 0)
    assert not source.finished(_state(0.1, [0.0, 0.0]))  # still at home: has not left
    assert not source.finished(_state(0.5, [0.3, 0.0]))  # left
    assert not source.finished(_state(0.9, [0.005, 0.0], qd=0.2))  # back but still moving
    assert source.finished(_state(1.0, [0.005, 0.0]))
    assert source.end(round(1.0e9), False) == {"success": True, "cycle_time_s": 1.0}
    assert source.end(round(1.0e9), True)["success"] is False  # the cell was stopped in the cycle


def test_fixed_time_and_digital_input_edges():
    timed = FixedTime(2.0, 1_000_000)
    timed.begin(0, round(1e9))
    assert not timed.finished(_state(2.9, [0.0])) and timed.finished(_state(3.0, [0.0]))

    class Plc:
        name, level, digital_inputs = "plc", True, ("part_done",)

        def digital_input(self, name):
            assert name == "part_done"
            return self.level

    plc = Plc()
    source = DigitalInput(plc, "part_done")
    source.begin(0, 0)  # high at the start: not an edge
    assert not source.finished(None)
    plc.level = False
    assert not source.finished(None)
    plc.level = True
    assert source.finished(None)


def test_a_source_the_robot_cannot_offer_is_refused_naming_the_key():
    class Bridge:
        name = "some-bridge"

    with pytest.raises(ScenarioError, match="cycle.source: 'task' needs a simulated cell"):
        make_cycle_source(CycleSettings(source="task"), Bridge(), None)
    with pytest.raises(ScenarioError, match="cycle.source: 'input'"):
        make_cycle_source(CycleSettings(source="input"), Bridge(), None)
    with pytest.raises(ScenarioError, match="cycle.source: 'policy'"):
        make_cycle_source(CycleSettings(source="policy"), Bridge(), type("P", (), {"source": "x"})())


def test_an_input_the_robot_does_not_have_and_a_cycle_shorter_than_two_periods_are_refused():
    """Refused when the run is built, before its record: an unknown input failed at the first cycle and left a
    one-message record; a 1 us episode counted 4 cycles of 5 ms, success 100 %."""
    class Plc:
        name, digital_inputs, dt_ns = "plc", ("cycle_done",), 1_000_000

        def digital_input(self, name):
            return False

    with pytest.raises(ScenarioError, match="cycle.input: 'plc' has no digital input 'part_done'; it has: cycle_done"):
        make_cycle_source(CycleSettings(source="input", input="part_done"), Plc(), None)
    with pytest.raises(ScenarioError, match=r"cycle.seconds: 1e-06 s is shorter than two servo periods \(0.002 s\)"):
        make_cycle_source(CycleSettings(source="time", seconds=1e-6), Plc(), None)


@pytest.mark.parametrize("cycle", [{"source": "time", "seconds": 6.0}, {"source": "home", "tolerance": 0.01}])
def test_a_hardware_source_on_a_simulated_cell_still_presents_each_part_and_the_cell_judges_it(cycle):
    """The part stayed on the drop zone after the first cycle: the gripper shut on nothing and every cycle read
    success."""
    run = Run(parse_scenario({"cell": "arm-pick-place", "seed": 4, "acceptance_cycles": 3, "production_cycles": 0,
                              "cycle": cycle}))
    outcomes = [run.cycle() for _ in range(3)]
    assert all(o["success"] and o["grasped"] for o in outcomes), outcomes
    assert len({round(o["place_error_mm"], 6) for o in outcomes}) == 3  # three parts, each placed and measured


def test_the_arm_cell_ends_cycles_on_its_home_pose_like_its_task_does():
    task = Run(parse_scenario({"cell": "arm-pick-place", "seed": 4, "acceptance_cycles": 1, "production_cycles": 0}))
    home = Run(parse_scenario({"cell": "arm-pick-place", "seed": 4, "acceptance_cycles": 1, "production_cycles": 0,
                               "cycle": {"source": "home", "tolerance": 0.01}}))
    a, b = task.cycle(), home.cycle()
    assert a["success"] and b["success"]
    assert abs(a["cycle_time_s"] - b["cycle_time_s"]) < 0.2


def test_a_policy_whose_first_chunk_is_refused_never_moves_the_arm_and_its_timed_cycle_fails(tmp_path):
    """A first chunk 100 rad off every joint: no approach towards it (it was clipped into the limits and
    played), the guard refuses it, and a fixed-time cycle in which the cell was stopped is no success."""
    far = tmp_path / "far.npz"
    q0 = make_cell("arm-pick-place").read().q
    np.savez(far, t=np.array([0.0]), actions=np.tile(q0 + 100.0, (1, 10, 1)), dt=np.array(0.05))
    run = Run(parse_scenario({"cell": "arm-pick-place", "seed": 4, "acceptance_cycles": 1, "production_cycles": 0,
                              "policy": f"replay:{far}", "cycle": {"source": "time", "seconds": 1.0}}))
    outcome = run.cycle()
    kinds = [e.kind for e in run.events]
    assert "chunk_rejected" in kinds and "watchdog_no_first_chunk" in kinds
    assert "approach_begin" not in kinds and outcome["success"] is False
    assert float(np.abs(run.link.state.q - q0).max()) < 0.01


def test_event_and_cycle_windows_stay_bounded_and_keep_absolute_indices():
    log = EventLog(window=100)
    for i in range(1000):
        log.append(Event(i, "overrun" if i % 2 else "resume", "x"))
    assert len(log) == 1000 and len(list(log)) == 100
    assert [e.t_ns for e in log[995:]] == [995, 996, 997, 998, 999]
    assert log.since(0)[0].t_ns == 900  # older ones live in the record only
    cycles = CycleWindow(window=50)
    for i in range(500):
        cycles.append({"cycle": i, "phase": "production", "success": i % 4 != 0})
    assert len(cycles) <= 55 and cycles[-1]["cycle"] == 499
    assert cycles.phases()["production"] == {"cycles": 500, "success_rate": 0.75}


def test_a_policy_episode_ends_only_after_the_policy_said_it_was_running():
    class Policy:
        source, done = "test:episodes", True

        def episode_done(self):
            return self.done

    policy = Policy()
    source = PolicyEpisodeEnd(policy)
    source.begin(0, 0)
    assert not source.finished(None)  # the last episode's end, before the worker reset the policy
    policy.done = False
    assert not source.finished(None)
    policy.done = True
    assert source.finished(None) and source.end(round(2e9), False) == {"success": True, "cycle_time_s": 2.0}
