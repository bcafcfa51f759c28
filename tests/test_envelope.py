"""The envelope on the MuJoCo arm cell: transparency, stops 0/1/2, safety inputs, watchdog, gate, box."""

from __future__ import annotations

import numpy as np
import pytest

from cellguard.control.config import GuardConfig
from cellguard.control.settings import build_guard
from cellguard.policy.chunk import ActionChunk
from cellguard.policy.scripted_arm import ScriptedArmPolicy
from cellguard.robot.protocol import SafetyInputs
from cellguard.robot.registry import make_cell
from cellguard.runtime import Run
from cellguard.scenario import load_scenario

SCENARIOS = __import__("pathlib").Path(__file__).parents[1] / "scenarios"


class Loop:
    """The tick path of the runner, on the arm cell, with a hook per tick."""

    def __init__(self, settings: GuardConfig | None = None, speed: float = 1.0, playback: bool = True):
        """``playback``: the program reads the playback clock (a speed override slows it, as a taught
        robot program's does); else it answers in real time, as a policy does."""
        self.cell = make_cell("arm-pick-place", seed=1)
        self.guard = build_guard(self.cell, settings)
        self.executor, self.envelope = self.guard.executor, self.guard.envelope
        self.policy = ScriptedArmPolicy(calibration=self.cell.context())
        self.cell.begin_cycle(0)
        self.policy._t0_ns = 0
        self.policy._program = self.policy._plan(self.cell.observe())
        self.program = lambda t: self.policy._at(np.asarray(t) * speed)
        self.playback = playback
        self.events, self.log = [], []

    def run(self, ticks: int, hook=None, silent_after: int | None = None, uncertainty=None) -> np.ndarray:
        """``uncertainty(k)``: the policy's uncertainty for the chunk sent at tick ``k`` (default: none)."""
        cell, ex, env = self.cell, self.executor, self.envelope
        for k in range(ticks):
            t = cell.t_ns
            if k % 50 == 0 and (silent_after is None or k < silent_after):
                # a taught program reads the playback clock (speed override), so a slowed clock slows it
                steps = ((ex.tau_ns if k and self.playback else t) + (np.arange(25) + 1) * 20_000_000) * 1e-9
                unsure = None if uncertainty is None else np.full(25, uncertainty(k))
                self.events += self.guard.push(ActionChunk(self.program(steps), t, 20_000_000, unsure), t)
            if hook is not None:
                hook(k, self)
            setpoint, events = self.guard.tick(t, cell.read(), cell.safety())
            reference = self.guard.reference
            self.events += events
            if not env.power:
                cell.set_power(False)
            cell.write(setpoint)
            cell.step()
            self.log.append((reference.copy(), setpoint.copy(), env.tool_speed, env.power))
        return np.array([s for _, s, _, _ in self.log])


def _kinds(events) -> list[str]:
    return [e.kind for e in events]


def test_a_reference_inside_the_envelope_passes_exactly():
    loop = Loop(speed=0.6)  # the taught program slowed into every limit of the profile
    loop.run(2000)
    ref = np.array([r for r, _, _, _ in loop.log])
    sent = np.array([s for _, s, _, _ in loop.log])
    assert np.array_equal(ref, sent)
    assert not [e for e in loop.events if e.kind not in ("chunk_steps_dropped",)]


@pytest.mark.parametrize("category", [0, 1, 2])
def test_protective_stop_input_is_obeyed_through_the_cell(category):
    loop = Loop(speed=0.6)

    def hook(k, lp):
        if k == 700:
            lp.cell.safety_inputs = SafetyInputs(stop=category)

    sent = loop.run(1400, hook)
    v = np.diff(sent, axis=0) / 1e-3
    moving = np.flatnonzero(np.abs(v[699:]).max(axis=1) > 0)
    settle_ms = (moving[-1] + 1) if len(moving) else 0
    kinds = _kinds(loop.events)
    assert "protective_stop" in kinds
    stop = next(e for e in loop.events if e.kind == "protective_stop")
    assert stop.category == category
    if category == 0:
        assert settle_ms <= 1 and "power_removed" in kinds
    else:
        assert settle_ms <= 400
        assert ("power_removed" in kinds) == (category == 1)
    assert loop.envelope.power == (category == 2)
    if category != 2:  # brakes hold the arm where it stopped
        qd = loop.cell.read().qd
        assert np.abs(qd).max() < 0.05


def test_protective_stop_released_resumes_motion():
    loop = Loop(speed=0.6)

    def hook(k, lp):
        lp.cell.safety_inputs = SafetyInputs(stop=2) if 600 <= k < 900 else SafetyInputs()

    loop.run(1500, hook)
    assert _kinds(loop.events).count("resume") == 1
    tail = np.array([s for _, s, _, _ in loop.log[-100:]])
    assert np.abs(np.diff(tail, axis=0)).max() > 0  # moving again


def test_watchdog_stops_a_silent_policy():
    loop = Loop(GuardConfig(watchdog_s=0.1), speed=0.6)
    sent = loop.run(900, silent_after=300)
    stop = [e for e in loop.events if e.kind == "watchdog_stop"]
    assert len(stop) == 1 and stop[0].category == 2
    assert 0.35e9 < stop[0].t_ns < 0.45e9  # last chunk at 0.25 s, watchdog 0.1 s
    assert np.abs(np.diff(sent[-100:], axis=0)).max() == 0.0


def test_reduced_speed_input_caps_the_tool_speed_and_keeps_the_path():
    fast = Loop()
    fast.run(1300)
    slow = Loop()

    def hook(k, lp):
        lp.cell.safety_inputs = SafetyInputs(reduced_speed=True)

    slow.run(1300, hook)
    assert max(s for _, _, s, _ in fast.log) > 0.4
    assert max(s for _, _, s, _ in slow.log[400:]) <= 0.25 * 1.05  # after the ramp-down
    assert "reduced_speed_input" in _kinds(slow.events)
    # the slowed clock keeps the path: once slowed, the reference is under the cap and passes exactly
    assert all(np.array_equal(r, s) for r, s, _, _ in slow.log[400:])


def _tool_speeds(loop: Loop) -> np.ndarray:
    """The tool speed of the setpoints sent [m/s], from the cell's kinematics (not the envelope's own figure)."""
    tips = np.array([loop.cell.tool_point(s) for _, s, _, _ in loop.log])
    return np.linalg.norm(np.diff(tips, axis=0), axis=1) / 1e-3


@pytest.mark.parametrize("settings, reduced, cap", [(None, True, 0.25), (GuardConfig(tool_speed_max=0.3), False, 0.3),
                                                    (GuardConfig(uncertainty_threshold=0.5), False, 0.25)])
def test_a_speed_cap_holds_the_sent_setpoints_of_a_policy_that_answers_in_real_time(settings, reduced, cap):
    """The slowed playback clock alone left them at 0.95 m/s: each chunk is placed where the program is now,
    so the reference jumped ahead of the clock and the tracker caught up at full joint speed."""
    loop = Loop(settings, playback=False)

    def hook(k, lp):
        lp.cell.safety_inputs = SafetyInputs(reduced_speed=reduced)

    loop.run(1300, hook, uncertainty=lambda k: 0.9)
    speeds = _tool_speeds(loop)
    assert speeds.max() <= cap * 1.01 and speeds.max() > 0.5 * cap  # capped from rest (no ramp), still moving
    sent = np.array([s for _, s, _, _ in loop.log])
    assert (np.abs(np.diff(sent, axis=0)) <= loop.cell.profile.array("velocity") * 1e-3 * 1.002).all()


def test_a_reference_under_the_speed_cap_passes_exactly():
    # the program at 0.6 peaks at 0.318 m/s in its first 2 s: the playback clock slows for a stretch ahead
    # faster than 0.9 of the cap, so this cap leaves the reference as it is
    loop = Loop(GuardConfig(tool_speed_max=0.36), speed=0.6)
    loop.run(2000)
    assert 0.31 < _tool_speeds(loop).max() < 0.36
    assert all(np.array_equal(r, s) for r, s, _, _ in loop.log)
    assert not [e for e in loop.events if e.kind not in ("chunk_steps_dropped",)]


def test_uncertainty_gate_holds_when_the_policy_is_unsure():
    loop = Loop(GuardConfig(uncertainty_threshold=0.5, uncertainty_action="hold"), speed=0.6)
    loop.run(600, uncertainty=lambda k: 0.9 if k >= 300 else 0.1)
    assert [e.category for e in loop.events if e.kind == "uncertainty_hold"] == [2]
    assert loop.envelope.tracker.stopped


def test_uncertainty_gate_reduces_the_tool_speed_when_the_policy_is_unsure():
    loop = Loop(GuardConfig(uncertainty_threshold=0.5, uncertainty_action="reduce"))
    loop.run(1300, uncertainty=lambda k: 0.9)
    assert "uncertainty_gate" in _kinds(loop.events) and loop.envelope.power
    assert max(s for _, _, s, _ in loop.log[400:]) <= 0.25 * 1.05  # after the ramp-down


def test_tool_speed_cap_holds_in_normal_operation():
    loop = Loop(GuardConfig(tool_speed_max=0.3))
    loop.run(1300)
    speeds = [s for _, _, s, _ in loop.log]
    assert max(speeds[400:]) <= 0.3 * 1.05 and max(speeds) > 0.2  # capped, still moving
    assert not [e for e in loop.events if e.kind not in ("chunk_steps_dropped", "limit_intervention")]


def test_workspace_box_stops_before_the_tool_leaves_it():
    box = ((-0.45, -0.45, 0.05), (0.45, 0.45, 0.55))  # floor raised above the pick height
    loop = Loop(GuardConfig(box=box), speed=0.6)
    sent = loop.run(2500)
    assert "workspace_stop" in _kinds(loop.events)
    tips = np.array([loop.cell.tool_point(q) for q in sent])
    assert tips[:, 2].min() > 0.05  # the stop ends inside the box: look-ahead (without it: 4.8 mm below)


@pytest.mark.parametrize("name, kind", [("latency.yaml", "chunk_steps_dropped"), ("nan.yaml", "chunk_rejected")])
def test_fault_scenarios_run_to_completion_inside_the_limits(name, kind):
    run = Run(load_scenario(SCENARIOS / name))
    profile = run.cell.profile
    seen = []
    original = run.guard.envelope.apply

    def apply(*args, **kwargs):
        setpoint, events = original(*args, **kwargs)
        seen.append(setpoint.copy())
        return setpoint, events

    run.guard.envelope.apply = apply
    outcomes = [run.cycle() for _ in range(run.scenario.total_cycles)]
    assert len(outcomes) == 3 and outcomes[0]["success"]  # the fault starts at cycle 1
    assert kind in _kinds(run.events)
    sent = np.array(seen)
    assert (sent >= profile.q_min).all() and (sent <= profile.q_max).all()
    v = np.diff(sent, axis=0) / 1e-3
    a = np.diff(v, axis=0) / 1e-3
    assert (np.abs(v) <= profile.array("velocity") * 1.002).all()
    assert (np.abs(a) <= profile.array("acceleration") * 1.02).all()
