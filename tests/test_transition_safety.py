"""The approach and the retreat obey the safety controller's inputs as the guard does on the cycles' ticks: the
tool-speed cap in force (the reduced-speed input's 0.25 m/s, the guard's tool_speed_max), and a stop of the
category the input asks (IEC 60204-1: 0 removes power at once, 1 after braking, 2 brakes and holds). They were
planned at the profile's full speed (0.66 m/s at the tool with the reduced-speed input held), and every stop input
aborted them as a category 2 stop, power kept on."""

from __future__ import annotations

from collections.abc import Callable

import mujoco
import numpy as np
import pytest

from cellguard.control.settings import build_guard
from cellguard.robot.protocol import RobotLinkError, SafetyInputs
from cellguard.runtime import Run
from cellguard.scenario import parse_scenario

REDUCED = 0.25  # [m/s] the reduced speed at the tool (ISO 10218-1), GuardConfig's default
# one 2.5 s cycle ends away from home: a retreat of 0.6 s at full speed follows, from 2.5 s on
ONE_CYCLE = {"cell": "arm-pick-place", "seed": 3, "acceptance_cycles": 1, "production_cycles": 0,
             "cycle": {"source": "time", "seconds": 2.5}}


class Watched:
    """A run whose cell reads the safety inputs ``inputs(t [s])`` gives; every setpoint written and every drive
    power switch is kept, with the simulated time [s] and the events so far. From ``lost`` [s] on, every read
    fails with the link lost (a bridge whose robot is gone)."""

    def __init__(self, raw: dict, inputs: Callable[[float], SafetyInputs], away: np.ndarray | None = None,
                 lost: float | None = None):
        self.run = run = Run(parse_scenario(raw))
        cell = self.cell = run.cell
        if away is not None:  # the arm starts away from the program's first target: an approach is played
            q = cell.q_home + away
            cell.data.qpos[cell.drives.qadr] = q
            cell.write(q)
            mujoco.mj_forward(cell.model, cell.data)
            run.guard = build_guard(cell, run.scenario.guard)
        self.writes: list[tuple[float, int, np.ndarray]] = []
        self.power: list[tuple[float, bool]] = []
        write, set_power, read = cell.write, cell.set_power, cell.read
        cell.safety = lambda: inputs(cell.t_ns * 1e-9)
        if lost is not None:
            cell.read = lambda: read() if cell.t_ns * 1e-9 < lost else _gone()
        cell.write = lambda q: (self.writes.append((cell.t_ns * 1e-9, run.events.total, np.array(q))), write(q))[1]
        cell.set_power = lambda on: (self.power.append((cell.t_ns * 1e-9, on)), set_power(on))[1]
        try:
            run.run_cycles()
        finally:
            run.close()

    def events(self, kind: str) -> list:
        """Every event of ``kind``, in order."""
        return [e for e in self.run.events if e.kind == kind]

    def event(self, kind: str):
        """The first event of ``kind``."""
        found = self.events(kind)
        assert found, f"no {kind} event among {[e.kind for e in self.run.events]}"
        return found[0]

    def after(self, kind: str, until: str | None = None) -> np.ndarray:
        """The setpoints written once the event ``kind`` was raised (until the event ``until``), (n, D), the last one
        before it first."""
        kinds = [e.kind for e in self.run.events]
        first, end = (next((k for k, (_, total, _) in enumerate(self.writes) if total > kinds.index(kind)),
                           len(self.writes)) for kind in (kind, until or kind))
        end = len(self.writes) if until is None else end
        return np.array([q for _, _, q in self.writes[first - 1:end]])

    def times_after(self, kind: str) -> np.ndarray:
        """The simulated times [s] of the setpoints ``after(kind)`` gives."""
        return np.array([t for t, _, _ in self.writes][-len(self.after(kind)):])

    def tool_speeds(self, setpoints: np.ndarray) -> np.ndarray:
        """The tool point's speed [m/s] between consecutive setpoints, one servo period apart."""
        tips = np.array([self.cell.tool_point(q) for q in setpoints])
        return np.linalg.norm(np.diff(tips, axis=0), axis=1) / (self.cell.dt_ns * 1e-9)

    def within_limits(self, setpoints: np.ndarray, slack: float = 1.01) -> bool:
        """No step of the setpoints beyond the velocity or acceleration limit (a plan swapped mid-way, a stop)."""
        dt, profile = self.cell.dt_ns * 1e-9, self.cell.profile
        v = np.diff(setpoints, axis=0) / dt
        a = np.diff(v, axis=0) / dt
        return bool((np.abs(v) <= profile.array("velocity") * slack).all()
                    and (np.abs(a) <= profile.array("acceleration") * slack).all())


def _gone():
    raise RobotLinkError("robot_read_failed", "bus gone", lost=True)


def test_with_the_reduced_speed_input_held_the_retreat_keeps_the_tool_under_the_reduced_speed():
    watched = Watched(ONE_CYCLE, lambda t: SafetyInputs(reduced_speed=True))
    assert watched.run.events.has("retreat_done")
    retreat = watched.after("retreat_begin")
    assert len(retreat) > 500  # a retreat was played
    assert watched.tool_speeds(retreat).max() <= REDUCED * 1.01  # 0.66 m/s at full speed


def test_a_reduced_speed_input_during_the_retreat_slows_it_under_the_cap_within_the_limits():
    on = 2.7  # [s] 0.2 s into the retreat, at speed
    watched = Watched(ONE_CYCLE, lambda t: SafetyInputs(reduced_speed=t >= on))
    assert watched.run.events.has("retreat_done")
    slowed = watched.event("reduced_speed_input")
    assert "retreat slows down" in slowed.reason and slowed.t_ns * 1e-9 >= on - 0.002
    retreat = watched.after("retreat_begin")
    speeds = watched.tool_speeds(retreat)
    times = watched.times_after("retreat_begin")[1:]  # of each speed's second setpoint
    assert speeds[times < on].max() > 2 * REDUCED  # it was fast when the input came on
    assert speeds[times >= on + 0.2].max() <= REDUCED * 1.01  # under the cap once braked, to the end
    assert watched.within_limits(retreat)  # braked under the limits, no step where the plan changed


def test_the_approach_keeps_the_tool_under_the_guards_tool_speed_max():
    cap = 0.3  # [m/s]
    watched = Watched({**ONE_CYCLE, "guard": {"tool_speed_max": cap}}, lambda t: SafetyInputs(),
                      away=np.array([0.6, 0.3, -0.4, 0.0, 0.0, 0.0]))
    approach = watched.after("approach_begin", until="approach_done")
    assert len(approach) > 100
    assert watched.tool_speeds(approach).max() <= cap * 1.01


def test_a_category_0_input_during_the_retreat_removes_power_at_once_and_moves_nothing_more():
    watched = Watched(ONE_CYCLE, lambda t: SafetyInputs(stop=0 if t >= 2.7 else None))
    run = watched.run
    aborted, removed = watched.event("retreat_aborted"), watched.event("power_removed")
    assert aborted.category == 0 and removed.category == 0 and removed.t_ns == aborted.t_ns
    assert watched.power == [(aborted.t_ns * 1e-9, False)]  # power off at the abort, never back on
    assert len(watched.after("retreat_aborted")) == 1  # the last setpoint before it, nothing written after
    assert not run.guard.power and run.stopped.startswith("power removed by a category 0 stop")


def test_a_category_1_input_during_the_retreat_brakes_under_the_limits_then_removes_power():
    watched = Watched(ONE_CYCLE, lambda t: SafetyInputs(stop=1 if t >= 2.7 else None))
    run = watched.run
    aborted, removed = watched.event("retreat_aborted"), watched.event("power_removed")
    assert aborted.category == 1 and removed.category == 1 and removed.t_ns > aborted.t_ns
    braking = watched.after("retreat_aborted")
    assert np.abs(braking[1] - braking[0]).max() > 1e-4  # it was moving at the abort
    assert watched.within_limits(braking) and np.abs(braking[-1] - braking[-2]).max() < 1e-6  # braked to rest
    assert [on for _, on in watched.power] == [False] and watched.power[0][0] >= removed.t_ns * 1e-9
    assert not run.guard.power and run.stopped.startswith("power removed by a category 1 stop")


def test_a_category_2_input_during_the_retreat_brakes_and_holds_with_power_kept():
    watched = Watched(ONE_CYCLE, lambda t: SafetyInputs(stop=2 if t >= 2.7 else None))
    assert watched.event("retreat_aborted").category == 2
    assert watched.power == [] and not watched.run.events.has("power_removed") and watched.run.guard.power
    braking = watched.after("retreat_aborted")
    assert watched.within_limits(braking) and np.abs(braking[-1] - braking[-2]).max() < 1e-6


def test_a_category_2_pulse_during_the_retreat_ends_the_run_stopped_away_from_home():
    """The robot was left held 0.9 rad from home, power on, and the run ended clean (exit 0)."""
    watched = Watched(ONE_CYCLE, lambda t: SafetyInputs(stop=2 if 2.6 <= t < 2.8 else None))
    assert watched.event("retreat_aborted").category == 2 and watched.run.guard.power
    assert watched.run.stopped.startswith("the retreat was aborted by a category 2 stop")


def test_a_category_0_pulse_during_the_approach_leaves_the_power_off_until_the_next_cycles_reset():
    """The approach's new guard forgot the stop: power stayed on, and a pulse that had cleared left the cycle
    commanding as if nothing had happened."""
    raw = {**ONE_CYCLE, "acceptance_cycles": 2, "cycle": {"source": "time", "seconds": 1.0}}
    watched = Watched(raw, lambda t: SafetyInputs(stop=0 if 0.1 <= t < 0.15 else None),
                      away=np.array([0.6, 0.3, -0.4, 0.0, 0.0, 0.0]))
    run = watched.run
    aborted, removed, reset = (watched.event(kind) for kind in ("approach_aborted", "power_removed", "reset"))
    approach = watched.after("approach_begin", until="approach_aborted")
    assert np.abs(approach[-1] - approach[-2]).max() > 1e-4  # moving at the abort
    assert aborted.category == 0 and removed.t_ns == aborted.t_ns
    assert [on for _, on in watched.power] == [False, True]  # off at the abort, on only at the next cycle's reset
    assert watched.power[0][0] == aborted.t_ns * 1e-9 and reset.t_ns >= aborted.t_ns + 0.9e9  # a cycle later
    first_cycle = np.array([q for t, _, q in watched.writes if aborted.t_ns * 1e-9 <= t < reset.t_ns * 1e-9])
    assert np.abs(first_cycle - first_cycle[0]).max() < 1e-9  # held where the approach stopped, power off
    assert run.cycles.total == 2 and run.stopped is None


def test_no_reset_while_the_stop_input_is_held_and_the_run_ends_stopped():
    """The simulated operator reset the cell at the next cycle with the input still held; the stop removed power
    again at once, and each cycle ran out its time-out."""
    watched = Watched({**ONE_CYCLE, "acceptance_cycles": 3}, lambda t: SafetyInputs(stop=0 if t >= 1.0 else None))
    run = watched.run
    assert [on for _, on in watched.power] == [False] and not run.events.has("reset")
    assert run.cycles.total == 1 and "still held: no reset" in run.stopped


def test_the_reset_follows_once_the_stop_input_has_cleared():
    watched = Watched({**ONE_CYCLE, "acceptance_cycles": 2}, lambda t: SafetyInputs(stop=0 if 1.0 <= t < 2.0 else None))
    run = watched.run
    assert [on for _, on in watched.power] == [False, True] and run.events.has("reset")
    assert run.cycles.total == 2 and run.stopped is None


def _stricter(first: int, then: float):
    """The safety controller's input: category ``first`` from 2.6 s (0.1 s into the retreat, at speed), category 0
    from ``then`` [s] on."""
    return lambda t: SafetyInputs(stop=0 if t >= then else first if t >= 2.6 else None)


def test_a_category_0_input_during_a_category_2_brake_removes_power_on_its_tick_and_moves_nothing_more():
    """The brake was played to its end without reading the inputs again, and nothing read them after a category 2
    abort: the category 0 input never removed power, the run ended clean with it held."""
    watched = Watched(ONE_CYCLE, _stricter(2, 2.62))
    run = watched.run
    assert [e.category for e in watched.events("retreat_aborted")] == [2, 0]
    escalated, removed = watched.events("retreat_aborted")[1], watched.event("power_removed")
    assert escalated.t_ns == removed.t_ns == round(2.62e9) and removed.category == 0
    assert watched.power == [(removed.t_ns * 1e-9, False)]
    braking = watched.after("retreat_aborted")
    assert np.abs(braking[1] - braking[0]).max() > 1e-4  # it was moving at the abort
    assert all(t < 2.62 for t, _, _ in watched.writes)  # nothing written from the category 0 tick on
    assert not run.guard.power and run.stopped.startswith("power removed by a category 0 stop")


def test_a_category_0_input_during_a_category_1_brake_removes_power_at_once_not_after_the_brake():
    watched = Watched(ONE_CYCLE, _stricter(1, 2.62))
    removed = watched.event("power_removed")
    assert removed.category == 0 and removed.t_ns == round(2.62e9)  # category 1, 59 ms later
    assert all(t < 2.62 for t, _, _ in watched.writes)
    assert watched.run.stopped.startswith("power removed by a category 0 stop")


def test_a_category_0_input_while_a_category_1_stop_waits_for_standstill_removes_power_at_once():
    """After the brake, the guard holds until the joints read still; the stop it ticked with was the one of the
    abort, the inputs never read again."""
    plain = Watched(ONE_CYCLE, _stricter(1, 99.0)).event("power_removed")
    then = 2.67  # the brake ended at 2.662 s, the joints read still at 2.679 s
    assert plain.category == 1 and plain.t_ns > round(then * 1e9)
    watched = Watched(ONE_CYCLE, _stricter(1, then))
    removed = watched.event("power_removed")
    assert removed.category == 0 and removed.t_ns == round(then * 1e9)
    assert watched.events("retreat_aborted")[-1].category == 1  # the brake had ended: the guard tells the rest


def test_a_category_1_input_during_a_category_2_brake_removes_power_at_rest_and_the_run_ends_stopped():
    watched = Watched(ONE_CYCLE, lambda t: SafetyInputs(stop=1 if t >= 2.62 else 2 if t >= 2.6 else None))
    run = watched.run
    assert [e.category for e in watched.events("retreat_aborted")] == [2, 1]
    removed = watched.event("power_removed")
    assert removed.category == 1 and [on for _, on in watched.power] == [False]
    braking = watched.after("retreat_aborted")
    assert watched.within_limits(braking) and np.abs(braking[-1] - braking[-2]).max() < 1e-6  # braked to rest
    assert not run.guard.power and run.stopped.startswith("power removed by a category 1 stop")


@pytest.mark.parametrize("category", [1, 2])
@pytest.mark.parametrize("transition, away, lost", [("retreat", None, 2.7),
                                                    ("approach", np.array([0.6, 0.3, -0.4, 0.0, 0.0, 0.0]), 0.3)])
def test_a_link_lost_during_a_transition_under_category_1_or_2_removes_power_at_once_naming_it(category, transition,
                                                                                                away, lost):
    """A controlled stop needs the link: its brake went to the dead link, then under category 1 the guard waited out
    the stopping time on the last state read and removed power 'still moving ... anyway' a second later; under
    category 2 the run said the robot was "held where it braked, power on" of a robot whose link was gone."""
    watched = Watched({**ONE_CYCLE, "realtime": {"stop_category": category}}, lambda t: SafetyInputs(), away=away,
                      lost=lost)
    failed, aborted, removed = (watched.event(k) for k in ("robot_read_failed", f"{transition}_aborted",
                                                           "power_removed"))
    assert failed.category == category  # the scenario's category, as the link asked it
    assert aborted.t_ns == removed.t_ns == failed.t_ns  # on the tick that found the link lost
    assert removed.category == aborted.category == 0
    assert (f"robot link lost, robot_read_failed: bus gone; the category {category} stop cannot be commanded "
            "without it") in removed.reason
    assert watched.power == [(removed.t_ns * 1e-9, False)] and not watched.run.guard.power
    held = watched.after(f"{transition}_aborted")  # the setpoint before it, then any written after it
    assert (held == held[0]).all()  # nothing moves after it; the approach writes its last setpoint once more on the
    assert len(held) == {"retreat": 1, "approach": 2}[transition]  # tick, to the dead link (the retreat: nothing)
    assert watched.run.stopped == "robot link: robot_read_failed: bus gone"
