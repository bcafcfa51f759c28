"""A run whose tool point starts outside the workspace box (a robot left there, a sim-server cell posed there) ended
"policy lost: the guard rejected every chunk": each first chunk's target lay outside the box and was refused as the
policy's answer, whether the policy held the tool there or brought it back in. A first target no further out than
the tool is now taken to (as the approach and the guard's look-ahead let any motion from outside go); one further
out is rejected as a chunk (the next may be fine), and where every one is, the policy-lost line names the box, the
wall and both distances."""

from __future__ import annotations

import re
import time

import mujoco
import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from sim_server_util import HOME, served
from sim_server_util import scenario as served_scenario
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.control.settings import build_guard
from cellguard.record.reader import open_record
from cellguard.robot.bridges.sim_server import SimServerRobot
from cellguard.runtime import Run, run_scenario
from cellguard.scenario import parse_scenario

BOX = [[-0.45, -0.45, 0.005], [0.45, 0.45, 0.25]]  # holds the arm's home tool point (z 0.194 m)
OUT = np.array([0.0, -0.3, 1.5, 1.55, 0.0, 0.025])  # its tool point at z 0.283 m: 33 mm over the box
FURTHER = OUT + [0.0, 0.0, -0.3, 0.0, 0.0, 0.0]  # z 0.357 m: 107 mm over
# z 0.285 m: 34.8 mm over, no further out than OUT (35.2 mm allowed); the approach there from OUT goes 1 mm further
NEAR = np.array([-0.001, -0.108, 1.347, 1.504, -0.354, 0.025])
LOST = ("policy_lost", "chunk_rejected", "startup_refused")
START = (r"the tool point starts 33 mm outside the workspace box \[\[-0.45, -0.45, 0.005\], \[0.45, 0.45, 0.25\]\] "
         r"past its z max \(at \[0.175, 0.0, 0.283\] m\)")
REJECTED = (rf"^first target: {START} and the first target lies further out, 107 mm past its z max \(at \[0.181, 0.0, "
            r"0.357\] m\); nothing approached$")
LOST_LINE = (rf"^{START}, every first target or the way to it further out, none taken \(the last: the first target "
             r"lies further out, 107 mm past its z max \(at \[0.181, 0.0, 0.357\] m\)\)$")


def _policy(tmp_path, way: str):
    """A replay policy (a chunk every 100 ms, 25 steps of 20 ms) that holds ``OUT``, holds ``FURTHER``, brings
    the tool from ``OUT`` home in 1.5 s ("back"), or answers ``FURTHER`` ("jitter") or ``NEAR`` ("near") first and
    holds ``OUT`` after."""
    steps = np.arange(60)[:, None] * 0.1 + np.arange(25)[None, :] * 0.02
    x = np.clip(steps / 1.5, 0.0, 1.0)[:, :, None]
    ends = {"hold": (OUT, OUT), "further": (FURTHER, FURTHER), "back": (OUT, HOME)}.get(way, (OUT, OUT))
    actions = ends[0] + (ends[1] - ends[0]) * x * x * (3 - 2 * x)
    if way in ("jitter", "near"):
        actions[0] = FURTHER if way == "jitter" else NEAR
    np.savez(tmp_path / f"{way}.npz", t=np.arange(60) * 0.1, actions=actions, dt=np.float64(0.02))
    return tmp_path / f"{way}.npz"


def posed_run(policy, box) -> Run:
    """A 3 s time cycle of replay file ``policy`` on the simulated arm inside ``box``, the arm posed at ``OUT`` before
    the run (as a robot left there)."""
    run = Run(parse_scenario({"cell": "arm-pick-place", "seed": 1, "policy": f"replay:{policy}",
                              "acceptance_cycles": 1, "production_cycles": 0, "guard": {"box": [*map(list, box)]},
                              "cycle": {"source": "time", "seconds": 3}}))
    cell = run.cell
    cell.data.qpos[cell.drives.qadr] = OUT
    cell.write(OUT)
    mujoco.mj_forward(cell.model, cell.data)
    run.guard = build_guard(cell, run.scenario.guard)
    return run


def _posed_run(tmp_path, way: str) -> Run:
    """``posed_run`` of the policy ``way`` (``_policy``), its tool point 33 mm over the box."""
    run = posed_run(_policy(tmp_path, way), BOX)
    assert round(_over_ceiling(run, run.cell.read().q), 3) == 0.033
    return run


def _over_ceiling(run: Run, q: np.ndarray) -> float:
    """How far the tool point at ``q`` lies over the box's ceiling [m] (below 0: under it)."""
    return float(run.guard.tool(q)[2]) - BOX[1][2]


def test_a_policy_that_holds_the_tool_where_it_starts_outside_the_box_runs(tmp_path):
    run = _posed_run(tmp_path, "hold")
    summary = run_scenario(run.scenario, tmp_path / "out", run=run)
    kinds = [e["kind"] for e in summary["events"]]
    assert "stopped" not in summary and not set(LOST) & set(kinds), summary.get("stopped")
    assert kinds == ["retreat_begin", "retreat_done"]  # held out there, no workspace stop; home at the end
    assert _over_ceiling(run, run.cell.read().q) < 0.0


def test_a_policy_that_brings_the_tool_back_into_the_box_runs_and_ends_inside(tmp_path):
    run = _posed_run(tmp_path, "back")
    at_end = []
    summary = run_scenario(run.scenario, tmp_path / "out", run=run,
                           on_cycle=lambda _: at_end.append(_over_ceiling(run, run.link.state.q)))
    assert "stopped" not in summary and summary["events"] == [], summary["events"]
    assert at_end[0] < -0.05  # the policy brought it home, 56 mm under the ceiling


def test_a_first_target_further_out_is_rejected_and_the_lost_line_names_the_box_not_the_policy(tmp_path):
    run = _posed_run(tmp_path, "further")
    summary = run_scenario(run.scenario, tmp_path / "out", run=run)
    assert re.match(LOST_LINE, run.policy_lost), run.policy_lost
    rejected = [e for e in run.events if e.kind == "chunk_rejected"]
    assert len(rejected) > 1 and all(re.match(REJECTED, e.reason) for e in rejected), rejected[0].reason
    with open_record(tmp_path / "out") as rec:
        kinds = [e.kind for e in rec.events()]
    assert "approach_begin" not in kinds and "policy_lost" in kinds and summary["stopped"].startswith("policy lost")


def test_one_first_target_further_out_then_one_that_holds_runs(tmp_path):
    run = _posed_run(tmp_path, "jitter")
    summary = run_scenario(run.scenario, tmp_path / "out", run=run)
    kinds = [e["kind"] for e in summary["events"]]
    assert "stopped" not in summary and kinds[-2:] == ["retreat_begin", "retreat_done"], summary.get("stopped")
    assert kinds[:-2] and set(kinds[:-2]) == {"chunk_rejected"}, kinds  # the first answers only (was exit 2)


def test_a_first_target_no_further_out_whose_approach_goes_further_on_the_way_is_rejected_not_a_refused_start(
        tmp_path):
    """The target lies inside the grown box, the joint-space approach there 1 mm past it: the start was refused
    (StartupRefused, exit 2), saying the approach "leaves" a box the tool was never inside, where a target further
    out was only a rejected chunk."""
    run = _posed_run(tmp_path, "near")
    summary = run_scenario(run.scenario, tmp_path / "out", run=run)
    kinds = [e["kind"] for e in summary["events"]]
    assert "stopped" not in summary and kinds[-2:] == ["retreat_begin", "retreat_done"], summary.get("stopped")
    assert kinds[:-2] and set(kinds[:-2]) == {"chunk_rejected"}, kinds  # the first answers only; held OUT after
    why = summary["events"][0]["reason"]
    assert re.match(rf"^first target: {START} and the approach to the first target \[-0.001, -0.108, 1.347, 1.504, "
                    r"-0.354, 0.025\]: its tool point goes 1 mm past where it may go from its start outside the "
                    r"workspace box .* first past its z max 0.06 s in .*; nothing approached$", why), why
    assert "leaves" not in why


def _leave_outside(port: int) -> None:
    """Another client drives the served arm to ``OUT`` over 1.5 s and leaves it there."""
    robot = SimServerRobot(("127.0.0.1", port), read_timeout_s=1.0)  # a busy host: a slow read is no fault here
    try:
        q0 = robot.read().q
        for s in [*np.linspace(0.0, 1.0, 1500), *[1.0] * 300]:
            robot.write(q0 + (OUT - q0) * s * s * (3 - 2 * s))
            time.sleep(0.001)
            robot.read()
        assert np.abs(robot.read().q - OUT).max() < 0.01
    finally:
        robot.close()


def test_a_served_arm_left_outside_the_box_runs_and_a_first_target_further_out_is_one_line_naming_it(tmp_path):
    with served() as port:
        _leave_outside(port)
        hold = {**served_scenario(port, _policy(tmp_path, "hold")), "guard": {"box": BOX}}
        summary = run_scenario(parse_scenario(hold), tmp_path / "hold")
        kinds = [e["kind"] for e in summary["events"]]
        assert "stopped" not in summary and not set(LOST) & set(kinds), summary.get("stopped")
        assert "retreat_done" in kinds  # home again: pose it out there once more
        _leave_outside(port)
        (tmp_path / "s.yaml").write_text(
            f"cell: arm-pick-place\nrobot: sim-server:udp://127.0.0.1:{port}\n"
            f"policy: replay:{_policy(tmp_path, 'further')}\nacceptance_cycles: 1\nproduction_cycles: 0\n"
            "cycle: {source: time, seconds: 2}\nrealtime: {stale_s: 0.25, read_timeout_s: 0.1, "
            "overrun_budget: 1000000}\nguard: {box: [[-0.45, -0.45, 0.005], [0.45, 0.45, 0.25]]}\n")
        result = CliRunner().invoke(app, ["run", str(tmp_path / "s.yaml"), "--out", str(tmp_path / "further")])
    assert result.exit_code == 1, result.output  # the cell stopped: the policy lost, the box start named
    assert ("\nerror: the cell was stopped (policy_lost): policy lost: the tool point starts 33 mm outside the "
            "workspace box ") in result.stderr, result.stderr
    assert "every first target or the way to it further out" in result.stderr
    assert "107 mm past its z max" in result.stderr
    with open_record(tmp_path / "further") as rec:
        kinds = [e.kind for e in rec.events()]
    assert "approach_begin" not in kinds and {"chunk_rejected", "policy_lost"} <= set(kinds)


_coordinate = st.floats(-2.0, 2.0, allow_nan=False)


@given(st.tuples(_coordinate, _coordinate, _coordinate), st.tuples(_coordinate, _coordinate, _coordinate),
       st.tuples(*[st.floats(0.01, 1.0)] * 3), st.tuples(_coordinate, _coordinate, _coordinate))
def test_box_excess_is_positive_exactly_outside_and_names_a_wall_the_point_is_past(point, lo, size, probe):
    from cellguard.control.checks.workspace import box_excess  # here: without it the module's other tests still run

    hi = tuple(a + s for a, s in zip(lo, size))
    for p in (point, probe, tuple(a + 0.5 * s for a, s in zip(lo, size))):
        excess, wall = box_excess(np.asarray(p), np.asarray(lo), np.asarray(hi))
        outside = not all(a <= x <= b for x, a, b in zip(p, lo, hi))
        assert (excess > 0.0) == outside
        axis, side = "xyz".index(wall[0]), wall[2:]
        assert excess == (lo[axis] - p[axis] if side == "min" else p[axis] - hi[axis])
