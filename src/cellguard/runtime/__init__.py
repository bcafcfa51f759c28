"""The runtime: one tick loop for simulated cells and robot bridges, paced by a clock.

    loop         Run, run_scenario: policy -> executor -> envelope -> robot -> recorder
    build        the robot, clock and inference worker a scenario names
    clock        SimClock (steps physics), LockStepClock (a served cell stepped per command),
                 WallClock (sleeps, then spins to each deadline)
    servo_thread what the servo thread asks of the OS; idle_window: its idle time lent to the recorder
    cycles       where a cycle ends: the cell's task, a digital input, home pose, policy, time
    inference    simulated inference, or a thread/process worker; never blocks a tick
    link         watched robot reads and finite writes; link faults become stops
    startup      checks that refuse to move; transitions: approach and retreat
    timing       period error, compute time and overruns in bounded memory
    history      the run's events and cycle outcomes in bounded memory
    recovery     the scenario's recovery behaviour driving the cell after a failed check
    operator_stop  Ctrl-C, SIGTERM or SIGHUP as a stop input
    sim_server   ``cellguard sim-server``: a simulated cell served as a robot on wall time
"""

__all__ = ["Run", "run_scenario"]


def __getattr__(name: str):
    """``Run`` and ``run_scenario`` from ``loop`` on first use: a module of the runtime imported alone (the
    sim-server's, the clock) does not pull in the loop and its diagnosis (scipy: a second of every server start)."""
    if name in __all__:
        from cellguard.runtime import loop

        return getattr(loop, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])
