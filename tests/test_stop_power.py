"""A category 1 stop removes power once the machine has stopped (IEC 60204-1), not when its setpoint has: the
measured joints must read still too, or a stopping time of the profile must have passed since the setpoint did."""

from __future__ import annotations

import numpy as np
import pytest
from test_envelope import Loop

from cellguard.control.envelope import SETTLE_MIN_NS, STANDSTILL, Envelope, stopping_time_ns
from cellguard.robot.protocol import SafetyInputs
from cellguard.robot.registry import make_cell
from cellguard.robot.state import State

CELL = make_cell("arm-pick-place")
PROFILE, Q0, MS = CELL.profile, CELL.read().q, 1_000_000
STOP_AT = 300  # ticks of motion before the stop input


def _reference(k: int) -> np.ndarray:
    """Joint 0 swings inside every limit of the profile (0.7 rad/s at the stop)."""
    q = Q0.copy()
    q[0] += 0.3 * (1.0 - np.cos(3.0 * k * 1e-3))
    return q


def _run(category: int, measured_speed, ticks: int = 1000) -> tuple[Envelope, list]:
    """An envelope driven ``ticks`` ms, a stop of ``category`` from ``STOP_AT``; ``measured_speed(k, setpoint)``:
    joint 0's measured speed on tick ``k`` (None: no state given). Per tick: t, power, setpoint at rest, events."""
    envelope, log = Envelope(PROFILE, Q0, MS), []
    setpoint = Q0
    for k in range(ticks):
        t = k * MS
        speed = measured_speed(k, setpoint)
        state = None if speed is None else State(t, setpoint, np.array([speed] + [0.0] * (PROFILE.dof - 1)),
                                                 np.zeros(PROFILE.dof), np.zeros(PROFILE.dof))
        safety = SafetyInputs(stop=category) if k >= STOP_AT else SafetyInputs()
        setpoint, events = envelope.apply(t, _reference(k), state, safety)
        log.append((t, envelope.power, envelope.tracker.stopped, envelope.stop_complete, events))
    return envelope, log


def _power_off(log) -> tuple[int, object]:
    """The tick power went off and its power_removed event."""
    k = next(k for k, (_, power, *_) in enumerate(log) if not power)
    return k, next(e for e in log[k][4] if e.kind == "power_removed")


def test_power_stays_on_while_the_measured_arm_still_moves_after_its_setpoint_is_at_rest():
    """On the arm cell the setpoint came to rest 72 ms after the input with the arm still at 0.56 rad/s, 7.5 mrad
    short of the command, and power went off there."""
    loop = Loop(speed=0.6)
    measured = []

    def hook(k, lp):
        measured.append(np.abs(lp.cell.read().qd).max())  # the state this tick's guard.tick reads
        if k == 700:
            lp.cell.safety_inputs = SafetyInputs(stop=1)

    loop.run(1400, hook)
    powered = [p for *_, p in loop.log]
    off = powered.index(False)
    sent = np.array([s for _, s, _, _ in loop.log])
    last_move = 700 + int(np.flatnonzero(np.abs(np.diff(sent[700:], axis=0)).max(axis=1) > 0)[-1]) + 1
    assert measured[last_move + 2] > STANDSTILL  # the setpoint at rest, the arm still moving: the case at issue
    assert off > last_move and measured[off] < STANDSTILL
    event = next(e for e in loop.events if e.kind == "power_removed")
    assert event.category == 1 and event.asked == pytest.approx(measured[off]) and event.sent == STANDSTILL
    assert event.joint in PROFILE.joint_names and "complete" in event.reason


def test_power_is_removed_one_stopping_time_after_the_setpoint_rests_on_a_robot_that_never_reads_still():
    envelope, log = _run(1, lambda k, _: 1.0, ticks=1600)
    rest = next(k for k, (_, _, at_rest, *_) in enumerate(log) if k >= STOP_AT and at_rest)
    off, event = _power_off(log)
    limit = max(stopping_time_ns(PROFILE), SETTLE_MIN_NS)
    assert stopping_time_ns(PROFILE) == pytest.approx(0.215e9)  # the arm's base joints: 3 rad/s, 15 rad/s², 1000 rad/s³
    assert log[off][0] - log[rest][0] == pytest.approx(limit, abs=MS)
    assert not any(complete for *_, complete, _ in log[:off]) and log[off][3]
    assert event.asked == 1.0 and event.joint == PROFILE.joint_names[0] and "anyway" in event.reason


def test_a_speed_that_reads_nan_is_no_standstill():
    _, log = _run(1, lambda k, _: np.nan, ticks=1600)
    rest = next(k for k, (_, _, at_rest, *_) in enumerate(log) if k >= STOP_AT and at_rest)
    off, event = _power_off(log)
    assert off > rest and "anyway" in event.reason


def test_power_is_removed_as_the_setpoint_rests_where_no_state_is_given():
    _, log = _run(1, lambda k, _: None)
    rest = next(k for k, (_, _, at_rest, *_) in enumerate(log) if k >= STOP_AT and at_rest)
    off, event = _power_off(log)
    assert off == rest and event.asked is None and event.reason.startswith("category 1 stop complete")


def test_a_category_2_stop_is_complete_with_its_setpoint_at_rest_and_power_kept():
    _, log = _run(2, lambda k, _: 1.0, ticks=600)
    rest = next(k for k, (_, _, at_rest, *_) in enumerate(log) if k >= STOP_AT and at_rest)
    assert all(power for _, power, *_ in log)
    assert not any(complete for *_, complete, _ in log[:rest]) and all(complete for *_, complete, _ in log[rest:])


def test_a_category_1_stop_on_the_quadruped_waits_for_its_legs_to_read_still():
    """The quadruped's profile stops a setpoint in 40 ms, its loaded legs read still 0.4 to 0.5 s later: power went
    off 'anyway' at 0.85 rad/s on every category 1 stop."""
    from cellguard.runtime import Run
    from cellguard.scenario import parse_scenario

    run = Run(parse_scenario({"cell": "quadruped-turns", "seed": 3, "acceptance_cycles": 1, "production_cycles": 0,
                              "cycle": {"source": "time", "seconds": 2.5}}))
    cell = run.cell
    cell.safety = lambda: SafetyInputs(stop=1 if cell.t_ns >= 1_000_000_000 else None)
    try:
        run.run_cycles()
    finally:
        run.close()
    event = next(e for e in run.events if e.kind == "power_removed")
    assert "complete" in event.reason and event.asked < STANDSTILL
