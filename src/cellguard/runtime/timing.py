"""Period error and compute time of the wall-clock loop, in bounded memory.

Per tick: lateness (woke minus deadline), compute time (tick start to the wait) and what handing
the tick to the recorder cost the servo thread [ns]. The last ``window`` ticks are kept for
percentiles; counts and maxima cover the whole run. An
overrun is a tick that woke at least one period late. A pause between two stretches of ticks
(a cycle's end, before a transition: the robot holds its last setpoint) is no tick; it is
counted with its longest length.
"""

from __future__ import annotations

import numpy as np

WINDOW = 65_536  # ticks kept for percentiles (about a minute at 1 kHz)


class TickTiming:
    """Lateness and compute time per tick; overrun count; the last ``window`` ticks for percentiles."""

    def __init__(self, period_ns: int, window: int = WINDOW):
        self.period_ns = int(period_ns)
        self._late = np.zeros(window, dtype=np.int64)
        self._compute = np.zeros(window, dtype=np.int64)
        self._recorder = np.zeros(window, dtype=np.int64)
        self.recorded = 0  # ticks handed to the recorder
        self.max_recorder_ns = 0
        self.recorder_over_200us = 0
        self.ticks = 0
        self.overruns = 0
        self.late_twice = 0  # ticks two or more periods late
        self.max_late_ns = 0
        self.max_compute_ns = 0
        self.new_overrun = False  # the last tick was an overrun (the loop raises the event)
        self.pauses = 0  # stretches of ticks that began after their deadline
        self.max_pause_ns = 0

    def add(self, late_ns: int, compute_ns: int) -> None:
        i = self.ticks % len(self._late)
        self._late[i], self._compute[i] = late_ns, compute_ns
        self.ticks += 1
        self.new_overrun = late_ns >= self.period_ns
        if self.new_overrun:
            self.overruns += 1
            self.late_twice += late_ns >= 2 * self.period_ns
        self.max_late_ns = max(self.max_late_ns, late_ns)
        self.max_compute_ns = max(self.max_compute_ns, compute_ns)

    def recorder(self, cost_ns: int) -> None:
        """What handing one tick to the recorder took on the servo thread [ns]."""
        self._recorder[self.recorded % len(self._recorder)] = cost_ns
        self.recorded += 1
        if cost_ns > self.max_recorder_ns:
            self.max_recorder_ns = cost_ns
        if cost_ns > 200_000:
            self.recorder_over_200us += 1

    def pause(self, pause_ns: int) -> None:
        """A stretch of ticks begins ``pause_ns`` after the deadline the last one left."""
        self.pauses += 1
        self.max_pause_ns = max(self.max_pause_ns, int(pause_ns))

    def summary(self) -> dict:
        """Period error, compute time and the recorder's servo-thread cost [us] (p50/p99 over the window,
        max over the run), overruns."""
        n = min(self.ticks, len(self._late))
        if n == 0:
            return {"ticks": 0, "overruns": 0}
        late, compute = self._late[:n] * 1e-3, self._compute[:n] * 1e-3
        recorder = self._recorder[:min(self.recorded, len(self._recorder))] * 1e-3
        if len(recorder):
            recorder = {"recorder_tick_us": {"p50": float(np.percentile(recorder, 50)),
                                             "p99": float(np.percentile(recorder, 99)),
                                             "max": self.max_recorder_ns * 1e-3,
                                             "over_200us": self.recorder_over_200us}}
        else:
            recorder = {}
        return {**recorder, "ticks": self.ticks, "period_us": self.period_ns * 1e-3,
                "period_error_us": {"p50": float(np.percentile(late, 50)), "p99": float(np.percentile(late, 99)),
                                    "max": self.max_late_ns * 1e-3},
                "compute_us": {"p50": float(np.percentile(compute, 50)), "p99": float(np.percentile(compute, 99)),
                               "max": self.max_compute_ns * 1e-3},
                "overruns": self.overruns, "later_than_two_periods": self.late_twice,
                "pauses_between_stretches": {"count": self.pauses, "max_ms": self.max_pause_ns * 1e-6}}
