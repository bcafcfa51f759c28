"""The runtime: one tick loop for simulated cells and robot bridges, paced by a clock.

    loop         Run, run_scenario: policy -> executor -> envelope -> robot -> recorder
    clock        SimClock (steps physics), WallClock (sleeps, then spins to each deadline)
    cycles       where a cycle ends: the cell's task, a digital input, home pose, policy, time
    inference    simulated inference, or a thread/process worker; never blocks a tick
    link         watched robot reads and finite writes; link faults become stops
    startup      checks that refuse to move; transitions: approach and retreat
    timing       period error, compute time and overruns in bounded memory
"""

from cellguard.runtime.loop import Run, run_scenario

__all__ = ["Run", "run_scenario"]
