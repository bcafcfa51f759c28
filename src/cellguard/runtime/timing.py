"""Period error and compute time of the wall-clock loop, in bounded memory.

Per tick: lateness (woke minus deadline), compute time (tick start to the wait) and what handing
the tick to the recorder cost the servo thread [ns]. The last ``window`` ticks are kept for
percentiles; counts and maxima cover the whole run. An
overrun is a tick that woke at least one period late. A pause between two stretches of ticks
(a cycle's end, before a transition: the robot holds its last setpoint) is no tick; it is
counted with its longest length.
"""

from __future__ import annotations

import time

import numpy as np

WINDOW = 65_536  # ticks kept for percentiles (about a minute at 1 kHz)


class _Durations:
    """One duration per tick [ns]: the last ``window`` kept for percentiles, the count and maximum over the run."""

    def __init__(self, window: int):
        self._values = np.zeros(window, dtype=np.int64)
        self.count = 0
        self.max_ns = 0

    def add(self, ns: int) -> None:
        self._values[self.count % len(self._values)] = ns
        self.count += 1
        if ns > self.max_ns:
            self.max_ns = ns

    def summary_us(self) -> dict:
        """p50 and p99 over the window, max over the run [us]."""
        us = self._values[:min(self.count, len(self._values))] * 1e-3
        return {"p50": float(np.percentile(us, 50)), "p99": float(np.percentile(us, 99)), "max": self.max_ns * 1e-3}


class TickTiming:
    """Lateness, compute time and the recorder's cost per tick; overrun count; the last ``window`` ticks
    for percentiles."""

    def __init__(self, period_ns: int, window: int = WINDOW):
        self.period_ns = int(period_ns)
        self._late, self._compute, self._recorder = _Durations(window), _Durations(window), _Durations(window)
        self.overruns = 0
        self.late_twice = 0  # ticks two or more periods late
        self.recorder_over_200us = 0
        self.recorder_off_cpu = 0  # of those, calls the servo thread spent mostly waiting or preempted
        self.new_overrun = False  # the last tick was an overrun (the loop raises the event)
        self.pauses = 0  # stretches of ticks that began after their deadline
        self.max_pause_ns = 0

    @property
    def ticks(self) -> int:
        return self._late.count

    @property
    def max_late_ns(self) -> int:
        return self._late.max_ns

    def add(self, late_ns: int, compute_ns: int) -> None:
        self._late.add(late_ns)
        self._compute.add(compute_ns)
        self.new_overrun = late_ns >= self.period_ns
        if self.new_overrun:
            self.overruns += 1
            self.late_twice += late_ns >= 2 * self.period_ns

    def recorder(self, cost_ns: int, cpu_began_ns: int = 0) -> None:
        """What handing one tick to the recorder took on the servo thread [ns]; ``cpu_began_ns``: the
        thread's CPU time (``time.thread_time_ns``) when the call began, 0 where it was not taken.

        A call over 200 µs is counted, and as off the CPU when the thread ran less than half of it:
        it waited (for the GIL, a lock, a page) or was preempted, which the recorder's design must
        prevent. One that ran is its own work or interrupts the host handled on the thread's time:
        on this VM a 1 µs row copy with nothing else to do took up to 157 µs of CPU time in 90 s.
        """
        self._recorder.add(cost_ns)
        if cost_ns > 200_000:
            self.recorder_over_200us += 1
            if cpu_began_ns and 2 * (time.thread_time_ns() - cpu_began_ns) < cost_ns:
                self.recorder_off_cpu += 1

    def pause(self, pause_ns: int) -> None:
        """A stretch of ticks begins ``pause_ns`` after the deadline the last one left."""
        self.pauses += 1
        self.max_pause_ns = max(self.max_pause_ns, int(pause_ns))

    def summary(self) -> dict:
        """Period error, compute time and the recorder's servo-thread cost [us] (p50/p99 over the window,
        max over the run), overruns."""
        if self.ticks == 0:
            return {"ticks": 0, "overruns": 0}
        recorder = ({"recorder_tick_us": {**self._recorder.summary_us(), "over_200us": self.recorder_over_200us,
                                         "over_200us_off_cpu": self.recorder_off_cpu}}
                    if self._recorder.count else {})
        return {**recorder, "ticks": self.ticks, "period_us": self.period_ns * 1e-3,
                "period_error_us": self._late.summary_us(), "compute_us": self._compute.summary_us(),
                "overruns": self.overruns, "later_than_two_periods": self.late_twice,
                "pauses_between_stretches": {"count": self.pauses, "max_ms": self.max_pause_ns * 1e-6}}
