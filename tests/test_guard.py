"""The Guard facade and how the envelope combines its checks: the strictest stop wins, a stricter stop overrides."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from cellguard.control.config import GuardConfig
from cellguard.control.events import ROUTINE_EVENTS, EventKind
from cellguard.control.guard import Guard
from cellguard.control.settings import build_guard
from cellguard.policy.chunk import ActionChunk
from cellguard.robot.protocol import SafetyInputs
from cellguard.robot.registry import make_cell

CELL = make_cell("arm-pick-place")
PROFILE, Q0, MS = CELL.profile, CELL.read().q, 1_000_000


def test_the_strictest_of_two_stops_asked_on_one_tick_wins():
    guard = Guard(PROFILE, Q0, MS, GuardConfig(watchdog_s=0.1, watchdog_category=0))
    guard.push(ActionChunk(np.repeat(Q0[None], 5, axis=0), 0, 20 * MS), 0)
    guard.tick(MS)
    _, events = guard.tick(200 * MS, None, SafetyInputs(stop=2))  # watchdog (category 0) and the input (2)
    assert [(e.kind, e.category) for e in events] == [("watchdog_stop", 0), ("power_removed", 0)]
    assert not guard.power


def test_a_stricter_stop_overrides_the_one_in_force():
    guard = Guard(PROFILE, Q0, MS)
    guard.tick(MS, None, SafetyInputs(stop=2))
    assert guard.power
    _, events = guard.tick(2 * MS, None, SafetyInputs(stop=0))
    assert [(e.kind, e.category) for e in events] == [("protective_stop", 0), ("power_removed", 0)]
    assert not guard.power
    guard.reset(Q0)
    setpoint, events = guard.tick(3 * MS)
    assert guard.power and not events and np.array_equal(setpoint, Q0)


def test_build_guard_takes_the_cells_box_and_a_scenarios_settings():
    guard = build_guard(CELL, GuardConfig(watchdog_s=0.5))
    assert guard.config.box == CELL.workspace_box and guard.config.watchdog_s == 0.5
    assert GuardConfig is GuardConfig


@pytest.mark.parametrize("key, value", [("watchdog_s", 0.0), ("reduced_speed", 0.3), ("soft_margin", 0.5),
                                        ("effort_fraction", 1.5), ("box", ((0, 0, 0), (0, 1, 1))), ("nope", 1)])
def test_a_bad_setting_is_refused_naming_its_key(key, value):
    with pytest.raises(ValidationError, match=key):
        GuardConfig(**{key: value})


def test_event_kinds_keep_their_record_strings():
    assert EventKind.WATCHDOG_STOP == "watchdog_stop" and str(EventKind.CHUNK_STEPS_DROPPED) == "chunk_steps_dropped"
    assert ROUTINE_EVENTS == {"chunk_steps_dropped", "approach_begin", "approach_done", "retreat_begin", "retreat_done",
                              "recovery_start", "recovery_end", "cycle_buffer_full"}
    assert EventKind.REFERENCE_INVALID.category == 2 and EventKind.PROTECTIVE_STOP.category is None
    assert all(EventKind(f"{k}_cleared") for k in (EventKind.REDUCED_SPEED_INPUT, EventKind.UNCERTAINTY_GATE))


def test_kinematics_from_the_mjcf_agrees_with_the_cell_and_names_what_exists():
    from cellguard.embodiment import Kinematics
    from cellguard.errors import UnknownNameError
    from cellguard.robot.arm_cell import ASSETS

    kinematics = Kinematics.from_mjcf(ASSETS / "arm.xml", "tcp", PROFILE.joint_names)
    rng = np.random.default_rng(0)
    for q in rng.uniform(PROFILE.q_min, PROFILE.q_max, (20, PROFILE.dof)):
        np.testing.assert_allclose(kinematics.tool_point(q), CELL.tool_point(q), atol=1e-12)
    with pytest.raises(UnknownNameError, match="tcp"):
        Kinematics.from_mjcf(ASSETS / "arm.xml", "flange", PROFILE.joint_names)


def test_build_guard_prefers_the_cells_kinematics_to_its_live_model():
    from cellguard.embodiment import Kinematics
    from cellguard.robot.arm_cell import ASSETS, ArmPickPlace

    cell = ArmPickPlace(seed=0)
    cell.kinematics = Kinematics.from_mjcf(ASSETS / "arm.xml", "tcp", cell.profile.joint_names)
    guard = build_guard(cell)
    assert guard.envelope._tool.__self__ is cell.kinematics and guard.executor._tool.__self__ is cell.kinematics


def test_a_late_tick_lags_the_reference_instead_of_jumping_it():
    # on wall time a tick may wake 1.4 ms late; sampling the chunk 2.4 ms on would step the setpoint by
    # 2.4 periods of motion, which the tracker's 1 ms finite differences read as an acceleration spike
    def sway(t_obs_ns):
        steps = (t_obs_ns + np.arange(1, 51) * 20 * MS) * 1e-9
        actions = np.repeat(Q0[None], 50, axis=0)
        actions[:, 0] = Q0[0] + 0.1 * np.sin(np.pi * steps)
        return ActionChunk(actions, t_obs_ns, 20 * MS)

    guard = Guard(PROFILE, Q0, MS)
    t, setpoints, kinds = 0, [], []
    for k in range(1500):
        if k % 100 == 0:
            kinds += [e.kind for e in guard.push(sway(t), t)]
        t += 2_400_000 if k == 1000 else MS  # one tick 1.4 ms late
        setpoint, events = guard.tick(t)
        setpoints.append(setpoint[0])
        kinds += [e.kind for e in events]
    assert EventKind.LIMIT_INTERVENTION not in kinds and guard.envelope.tracker.passing
    steps = np.abs(np.diff(setpoints[900:1100]))
    assert steps[100] <= 1.05 * np.median(steps[95:105])  # the late tick moved as far as any other
    assert guard.executor.tau_ns == t - 1_400_000  # the time lost is lag of the playback clock


@pytest.mark.parametrize("setting", [{"box": ((-1.0, -1.0, 0.0), (1.0, 1.0, 1.0))}, {"tool_speed_max": 1e-4}])
def test_a_tool_setting_on_a_cell_without_a_tool_model_is_refused(setting):
    """On the quadruped both were accepted, recorded as in force and never checked."""
    from cellguard.errors import ConfigError

    with pytest.raises(ConfigError, match=f"guard.{next(iter(setting))}: cell quadruped-turns has no tool model"):
        build_guard(make_cell("quadruped-turns"), GuardConfig(**setting))
    build_guard(make_cell("arm-pick-place"), GuardConfig(**setting))  # the arm has one: accepted
