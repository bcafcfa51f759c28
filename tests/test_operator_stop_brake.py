"""A third stop signal never ends a brake mid-way: a held Ctrl-C repeats about 30 times a second, and its third
signal raised KeyboardInterrupt while the approach braked, the last setpoint at 2.2 rad/s (a dead stop for a drive
holding it) and nothing in the record. Within the longest brake of the signal before it, it is said on stderr,
raised once the command is at rest, and the record says so; later, it raises at once (a hung program still ends)."""

from __future__ import annotations

import signal
import time

import mujoco
import numpy as np
import pytest

from cellguard.control.settings import build_guard
from cellguard.runtime import Run
from cellguard.runtime.operator_stop import OperatorStop
from cellguard.scenario import parse_scenario


def test_three_signals_during_the_approach_brake_it_to_rest_before_keyboard_interrupt(capfd):
    run = Run(parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 1}))
    cell = run.cell
    q = cell.q_home + np.array([1.2, 0.6, -1.2, 0.0, 0.0, 0.0])  # the approach home reaches 3 rad/s
    cell.data.qpos[cell.drives.qadr] = q
    cell.write(q)
    mujoco.mj_forward(cell.model, cell.data)
    run.guard = build_guard(cell, run.scenario.guard)
    write, setpoints = cell.write, []

    def write_and_press(setpoint):  # at speed, three presses a few ticks apart (a key held down)
        setpoints.append(np.array(setpoint))
        if len(setpoints) in (200, 233, 266):
            signal.raise_signal(signal.SIGINT)
        return write(setpoint)

    cell.write = write_and_press
    with pytest.raises(KeyboardInterrupt):
        try:
            run.run_cycles()
        finally:
            run.close()
    steps = np.abs(np.diff(np.array(setpoints), axis=0)) / (cell.dt_ns * 1e-9)  # [rad/s] per write
    assert steps[198].max() > 2.0  # pressed at speed
    assert len(setpoints) > 266 and (steps <= cell.profile.array("velocity") * 1.001).all()
    assert steps[-1].max() < 1e-3  # at rest when it raised
    said = [e for e in run.events if e.kind == "operator_stop"][-1]
    assert "3 stop signals, 1 of them during the brake: KeyboardInterrupt, held until the command came to rest" \
        in said.reason
    assert "SIGINT again during the brake: KeyboardInterrupt once the robot is at rest" in capfd.readouterr().err


def test_a_signal_after_the_longest_brake_raises_at_once_and_at_rest_raises_one_held():
    with OperatorStop(brake_s=0.2) as operator:
        for _ in range(4):  # the third and fourth within the brake: held
            signal.raise_signal(signal.SIGINT)
        assert (operator.count, operator.waiting) == (4, 2)
        with pytest.raises(KeyboardInterrupt):
            operator.at_rest()
        assert operator.waiting == 0
        operator.at_rest()  # nothing held: nothing raised
        with pytest.raises(KeyboardInterrupt):  # no brake runs now: at once
            signal.raise_signal(signal.SIGINT)
    with OperatorStop(brake_s=0.2) as operator:
        signal.raise_signal(signal.SIGINT)
        signal.raise_signal(signal.SIGINT)
        time.sleep(0.25)
        with pytest.raises(KeyboardInterrupt):
            signal.raise_signal(signal.SIGINT)


def test_once_the_run_moves_no_more_a_third_signal_raises_at_once():
    """Signals while a run closes its record (no motion left) opened the brake's window, and the third was held for a
    rest that never came: swallowed. Once the cycles and the retreat are over, the third raises at once."""
    run = Run(parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 0,
                              "cycle": {"source": "time", "seconds": 0.5}}))
    try:
        with run.operator:
            run.run_cycles()
            signal.raise_signal(signal.SIGINT)
            signal.raise_signal(signal.SIGINT)
            with pytest.raises(KeyboardInterrupt):
                signal.raise_signal(signal.SIGINT)
            assert run.operator.waiting == 0
    finally:
        run.close()
