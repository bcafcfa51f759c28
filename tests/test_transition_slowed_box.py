"""A transition slowed mid-way by the reduced-speed input keeps the tool inside the workspace box: its new way on
(braked to rest, then on under the cap) was played unchecked, 2 mm past the box's y max on the way to a first target
inside it, approach_done, no event. Now the way on is checked from rest where the brake left the robot, and one that
leaves the box is not played, as a transition's that leaves it from the start: the approach refuses the start, the
retreat ends the run stopped, the robot held where it braked. The brake itself is one the transition was checked for
before it was played (``Transition.leaves_box``: a brake from any of its setpoints keeps inside)."""

from __future__ import annotations

from collections.abc import Callable

import mujoco
import numpy as np
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from cellguard.control.config import GuardConfig
from cellguard.control.reach import max_reach
from cellguard.control.settings import build_guard
from cellguard.robot.protocol import SafetyInputs
from cellguard.robot.registry import make_cell
from cellguard.runtime import Run
from cellguard.runtime.startup import StartupRefused
from cellguard.runtime.transitions import BRAKE_SLACK_S, SLACK, Transition, longest_brake_s
from cellguard.scenario import parse_scenario

CELL = make_cell("arm-pick-place")
PROFILE, HOME = CELL.profile, np.asarray(CELL.q_home, dtype=np.float64)
SOFT_LO, SOFT_HI = PROFILE.soft_limits(GuardConfig().soft_margin)
LONGEST_STOP_S = longest_brake_s(PROFILE, CELL.dt_ns) - BRAKE_SLACK_S  # the longest brake under the limits [s]
# an approach inside the default box whose way on, slowed 0.09 s in, went 2 mm past its y max; played in the box with
# a floor 55 mm lower (a brake of it at full speed goes 31 mm under the default floor: not played there)
START, FIRST = (np.array([-1.0444, 0.7696, -0.6019, -1.7699, -1.6269, 0.025]),
                np.array([-0.9661, -1.5909, -0.2227, -0.152, -0.6529, 0.025]))
LOWER_FLOOR = [[-0.45, -0.45, -0.05], [0.45, 0.45, 0.55]]
# an approach inside the default box whose brake 0.4 s in (each joint stopping on its own) goes 18 mm past it
BRAKED_FROM, BRAKED_TO = (np.array([0.2709, -0.3851, -1.1154, 1.4486, 2.0708, 0.025]),
                          np.array([0.9084, -1.628, 1.9883, -1.1936, 1.3336, 0.025]))
APPROACH = ("approach_begin", ("approach_done", "startup_refused"))  # its setpoints: ``Played.between(*APPROACH)``
# a pose the retreat home leaves inside the default box, whose way home slowed 0.11 s in went 2.7 mm past it
AWAY = np.array([1.2121, 1.6449, -1.3054, -1.7466, -2.5867, 0.025])


class Played:
    """A run of one 0.3 s time cycle of a replayed policy that holds ``target``, the arm at rest at ``start``, the
    safety inputs ``inputs(s)`` (s: seconds since the event ``since`` began, None before); every setpoint written is
    kept with the simulated time [s] and the number of events before it. ``refused``: the start refusal that ended
    it, if one did."""

    def __init__(self, tmp_path, start: np.ndarray, target: np.ndarray, inputs: Callable[[float | None], SafetyInputs],
                 since: str = "approach_begin", box: list | None = None):
        np.savez(tmp_path / "hold.npz", t=np.arange(40) * 0.1, actions=np.tile(target, (40, 25, 1)),
                 dt=np.float64(0.02))
        guard = {} if box is None else {"guard": {"box": box}}
        self.run = run = Run(parse_scenario({"cell": "arm-pick-place", "seed": 1, "acceptance_cycles": 1,
                                             "production_cycles": 0, "policy": f"replay:{tmp_path / 'hold.npz'}",
                                             "cycle": {"source": "time", "seconds": 0.3}, **guard}))
        cell = self.cell = run.cell
        cell.data.qpos[cell.drives.qadr] = start
        cell.write(start)
        mujoco.mj_forward(cell.model, cell.data)
        run.guard = build_guard(cell, run.scenario.guard)
        self.writes: list[tuple[float, int, np.ndarray]] = []
        write = cell.write
        cell.write = lambda q: (self.writes.append((cell.t_ns * 1e-9, run.events.total, np.array(q))), write(q))[1]
        began: list[float] = []

        def safety() -> SafetyInputs:
            began.extend(e.t_ns * 1e-9 for e in run.events if not began and e.kind == since)
            return inputs(cell.t_ns * 1e-9 - began[0] if began else None)

        cell.safety = safety
        self.refused = None
        try:
            run.run_cycles()
        except StartupRefused as exc:
            self.refused = str(exc)
        finally:
            run.close()

    def kinds(self) -> list[str]:
        return [e.kind for e in self.run.events]

    def between(self, first: str, ends: tuple[str, ...]) -> list[tuple[float, np.ndarray]]:
        """The setpoints written once the event ``first`` was raised, until the first of the events ``ends`` (to the
        last where none comes), (time [s], pose), in order; none where ``first`` never came."""
        kinds = self.kinds()
        if first not in kinds:
            return []
        begin = kinds.index(first)
        end = next((k for k in range(begin, len(kinds)) if kinds[k] in ends), len(kinds))
        return [(t, q) for t, total, q in self.writes if begin < total <= end]

    def excess(self, setpoints) -> np.ndarray:
        """How far each setpoint's tool point lies outside the guard's box [m] (below 0: inside)."""
        lo, hi = (np.asarray(corner) for corner in self.run.guard.config.box)
        tips = np.array([self.run.guard.tool(q) for q in setpoints]).reshape(-1, 3)
        return np.maximum(lo - tips, tips - hi).max(axis=1)


def _reduced_from(on: float) -> Callable[[float | None], SafetyInputs]:
    return lambda s: SafetyInputs(reduced_speed=s is not None and s >= on)


def test_an_approach_whose_slowed_way_on_leaves_the_box_is_braked_inside_it_and_refuses_the_start(tmp_path):
    played = Played(tmp_path, START, FIRST, _reduced_from(0.09), box=LOWER_FLOOR)
    assert played.refused is not None and played.refused.startswith(
        "start-up: the approach to the first target [-0.966, -1.591, -0.223, -0.152, -0.653, 0.025], slowed down by "
        "the reduced-speed input: its tool point leaves the workspace box")
    assert "past its y max" in played.refused and played.refused.endswith("; held where it braked")
    kinds = played.kinds()
    assert kinds[kinds.index("approach_begin"):] == ["approach_begin", "reduced_speed_input", "startup_refused"]
    approach = [q for _, q in played.between(*APPROACH)]
    assert len(approach) > 100 and played.excess(approach).max() < 0.0  # 2.0 mm past y max, unchecked
    assert np.abs(approach[-1] - approach[-2]).max() < 1e-6  # at rest where it braked, far from the target
    assert np.abs(approach[-1] - FIRST).max() > 1.0


def test_a_retreat_whose_slowed_way_home_leaves_the_box_is_not_played_beyond_its_brake(tmp_path):
    played = Played(tmp_path, AWAY, AWAY, _reduced_from(0.11), since="retreat_begin")
    run, kinds = played.run, played.kinds()
    assert kinds[kinds.index("retreat_begin"):] == ["retreat_begin", "reduced_speed_input", "retreat_aborted"]
    assert run.events[-1].reason.startswith("retreat not played beyond its brake: its tool point leaves the workspace "
                                            "box")
    assert run.stopped.startswith("the retreat home was not played beyond its brake: its tool point leaves")
    assert run.stopped.endswith("the robot is held where it stopped, power on: bring it home before the next run")
    retreat = [q for _, q in played.between("retreat_begin", ("retreat_done", "retreat_aborted"))]
    assert len(retreat) > 100 and played.excess(retreat).max() < 0.0  # 2.7 mm out, unchecked
    assert np.abs(retreat[-1] - retreat[-2]).max() < 1e-6 and np.abs(retreat[-1] - HOME).max() > 0.5


def test_a_slowed_way_on_that_keeps_to_the_box_is_played_to_the_target_under_the_cap(tmp_path):
    """Its brake took the tool 18 mm out at full speed (the approach is now played slower, its brakes inside); the
    way on from there keeps to the box's rule."""
    played = Played(tmp_path, BRAKED_FROM, BRAKED_TO, _reduced_from(0.4))
    kinds = played.kinds()
    assert played.refused is None and "approach_done" in kinds
    approach = played.between(*APPROACH)
    slowed = next(e.t_ns * 1e-9 for e in played.run.events if e.kind == "reduced_speed_input")
    way_on = [q for t, q in approach if t > slowed + LONGEST_STOP_S + 0.002]  # after its brake, played to the target
    assert len(way_on) > 100 and _keeps_to_the_box(played.excess(way_on)) and played.excess(way_on[-1:])[0] < 0.0
    assert np.abs(way_on[-1] - BRAKED_TO).max() < 1e-6


def _tight_box(start: np.ndarray, target: np.ndarray, margin: float) -> list[list[float]] | None:
    """The box around the tool's path from ``start`` to ``target`` at full speed (and the home pose's tool point),
    ``margin`` [m] to spare: the path runs along its faces. None where no transition is played."""
    tool = build_guard(CELL).tool
    plan = Transition.plan(PROFILE, start, target, CELL.dt_ns, reach=max_reach(tool, PROFILE.q_min, PROFILE.q_max).norm)
    if plan is None:
        return None
    tips = np.array([tool(q) for q in [start, HOME, *plan.setpoints()]])
    return [(tips.min(axis=0) - margin).tolist(), (tips.max(axis=0) + margin).tolist()]


poses = st.lists(st.floats(0.0, 1.0), min_size=PROFILE.dof - 1, max_size=PROFILE.dof - 1).map(
    lambda u: np.append(SOFT_LO[:-1] + np.array(u) * (SOFT_HI[:-1] - SOFT_LO[:-1]), HOME[-1]))


def _keeps_to_the_box(excess) -> bool:
    """Whether a transition's setpoints, of these excesses over the box [m] (``Played.excess``), keep its rule
    (``Transition.leaves_box``): one that starts outside goes no further out than it starts plus ``SLACK``, and that
    shrinks as it comes in; once inside, it stays inside."""
    allowed = None
    for x in excess:
        if allowed is None:  # the start
            allowed = x + SLACK if x > 0.0 else 0.0
        elif x > allowed:
            return False
        else:
            allowed = min(allowed, x + SLACK) if x > 0.0 else 0.0
    return True


@settings(max_examples=30, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(start=poses, target=poses, margin=st.floats(0.0005, 0.01), on=st.floats(0.0, 1.0))
@example(start=np.array([-2.4, -1.728, -2.4, 2.016, -2.784, 0.025]), target=np.array([-2.4, 1.728, -2.4, -2.016, -2.784,
         0.025]), margin=0.001953125, on=0.0)  # on at the first tick: 1.3 mm out 3.4 s in
def test_a_slowed_approach_plays_nothing_outside_the_box_but_its_brake(tmp_path, start, target, margin, on):
    """In a box drawn tight around the approach's path at full speed, with the reduced-speed input coming on at any
    time of it: outside the box, only the brake it starts (at most the longest stop's time after it), and from where
    that left the tool, by the box's rule for a transition that starts outside."""
    box = _tight_box(start, target, margin)
    if box is None:
        return
    duration = Transition.plan(PROFILE, start, target, CELL.dt_ns).duration_s
    played = Played(tmp_path, start, target, _reduced_from(on * duration), box=box)
    approach = played.between(*APPROACH)
    times, excess = np.array([t for t, _ in approach]), played.excess([q for _, q in approach])
    slowed = [e.t_ns * 1e-9 for e in played.run.events if e.kind == "reduced_speed_input"] or [np.inf]
    before, after = times < slowed[0], times > slowed[0] + LONGEST_STOP_S + 0.002
    assert _keeps_to_the_box(excess[before]) and _keeps_to_the_box(excess[after]), (times[excess > 0], slowed)
