"""The approach and the retreat keep the tool inside the workspace box, checked at every setpoint before one is
played: planned in joint space under the limits alone, the approach to a first target 18 mm above the table went
145 mm under it on the way (and the retreat home from there), about 2 s outside the box, no event, exit 0. An
approach whose path leaves the box refuses the start (nothing moves); a retreat's is not played (the robot holds
where it stopped and the run ends stopped)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from cellguard.control.settings import build_guard
from cellguard.runtime import Run
from cellguard.runtime.startup import StartupRefused
from cellguard.scenario import parse_scenario

# the tool point 18 mm above the table, inside the default box; the joint-space line from home to it dives under it
LOW = np.array([0.297, -1.559, -2.31, -1.096, -0.604, 0.025])
# a pose the line from home reaches inside the box all the way
INSIDE = np.array([1.2, 0.3, 0.7, 1.55, 0.0, 0.025])


def _watched(tmp_path, target: np.ndarray, start: np.ndarray | None = None) -> tuple[Run, list[np.ndarray]]:
    """A run of one 3 s time cycle of a replayed policy that holds ``target``, the arm at ``start`` (default home);
    every setpoint written is kept."""
    np.savez(tmp_path / "hold.npz", t=np.arange(40) * 0.1, actions=np.tile(target, (40, 25, 1)), dt=np.float64(0.02))
    run = Run(parse_scenario({"cell": "arm-pick-place", "seed": 1, "policy": f"replay:{tmp_path / 'hold.npz'}",
                              "acceptance_cycles": 1, "production_cycles": 0,
                              "cycle": {"source": "time", "seconds": 3}}))
    cell, written = run.cell, []
    if start is not None:
        cell.data.qpos[cell.drives.qadr] = start
        cell.write(start)
        mujoco.mj_forward(cell.model, cell.data)
        run.guard = build_guard(cell, run.scenario.guard)
    write = cell.write
    cell.write = lambda q: (written.append(np.array(q)), write(q))[1]
    return run, written


def _tool_excess(run: Run, setpoints) -> float:
    """How far the setpoints take the tool point out of the guard's box at most [m] (below 0: inside)."""
    lo, hi = (np.asarray(corner) for corner in run.guard.config.box)
    tips = np.array([run.guard.tool(q) for q in setpoints])
    return float(np.maximum(lo - tips, tips - hi).max())


def test_an_approach_whose_path_leaves_the_box_refuses_the_start_and_moves_nothing(tmp_path):
    run, written = _watched(tmp_path, LOW)
    start = run.cell.read().q
    assert run.guard.envelope.target_problem(LOW) is None  # the target itself is inside the box
    with pytest.raises(StartupRefused, match=r"approach to the first target .* leaves the workspace box .* past its z max"):
        try:
            run.run_cycles()
        finally:
            run.close()
    refused = [e for e in run.events if e.kind == "startup_refused"]
    # the worst is told with its own wall: the path crosses the ceiling first, then dives under the floor
    assert len(refused) == 1 and refused[0].reason.endswith("; 145 mm outside at worst, past its z min 1.29 s in; "
                                                            "not moving")
    assert not run.events.has("approach_begin")
    assert np.abs(np.array(written) - start).max() < 1e-9  # nothing moved


def test_a_retreat_whose_path_leaves_the_box_is_not_played_and_the_run_ends_stopped(tmp_path):
    run, written = _watched(tmp_path, LOW, start=LOW)  # no approach: the arm is there already
    try:
        run.run_cycles()
    finally:
        run.close()
    kinds = [e.kind for e in run.events]
    assert "retreat_begin" not in kinds and kinds[-1] == "retreat_aborted"
    assert "retreat not played: its tool point leaves the workspace box" in run.events[-1].reason
    assert run.stopped.startswith("the retreat home was not played") and "bring it home" in run.stopped
    assert _tool_excess(run, written) <= 0.0  # the tool never left the box
    assert np.abs(written[-1] - LOW).max() < 0.01  # held where it stopped, away from home


def test_transitions_inside_the_box_are_played_as_before(tmp_path):
    run, written = _watched(tmp_path, INSIDE)
    try:
        run.run_cycles()
    finally:
        run.close()
    kinds = [e.kind for e in run.events]
    assert [k for k in kinds if k.startswith(("approach", "retreat"))] == [
        "approach_begin", "approach_done", "retreat_begin", "retreat_done"]
    assert run.stopped is None and _tool_excess(run, written) <= 0.0
    assert np.abs(written[-1] - run.cell.q_home).max() < 1e-6
