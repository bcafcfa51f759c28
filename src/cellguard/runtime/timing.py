"""Period error and compute time of the wall-clock loop, in bounded memory.

Per tick: lateness (woke minus deadline), compute time (tick start to the wait) and what handing
the tick to the recorder cost the servo thread [ns]; on wall time also why a call over 200 µs was
slow (``SlowCalls``). Percentiles, counts and maxima cover the whole run: each duration is
counted in a log-bucket histogram (``_Durations``), in memory that does not grow (a window of the
last 65,536 ticks made a 300 s run's p99 that of its last minute). An overrun is a tick that woke
at least one period late. A pause between two stretches of ticks (a cycle's end, before a
transition: the robot holds its last setpoint) is no tick; it is counted with its longest length.
"""

from __future__ import annotations

import resource
import time

import numpy as np

SUB_BITS = 7  # 2**7 buckets per octave: 1 ns wide below 256 ns, above at most 1/128 (0.8 %) of the value
EXACT = (2 << SUB_BITS) - 1  # durations up to this have a bucket each [ns]
BUCKETS = (63 - SUB_BITS + 1) << SUB_BITS  # enough for any duration below 2**63 ns (a monotonic_ns difference)
SLOW_NS = 200_000  # a recorder call longer than this is counted, and on wall time explained [ns]


def _bucket_bounds(index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lowest duration and width of histogram buckets ``index`` [ns] (``_Durations.add`` inverted)."""
    shift = np.maximum((index >> SUB_BITS) - 1, 0)
    return np.where(index <= EXACT, index, (index - (shift << SUB_BITS)) << shift), np.left_shift(1, shift)


class _Durations:
    """One duration per tick [ns, >= 0], counted in a log-bucket histogram: percentiles over the whole
    run in fixed memory (a bucket is 1 ns, or at most 0.8 % of its durations, wide)."""

    def __init__(self):
        self._counts = [0] * BUCKETS
        self.max_ns = 0

    def add(self, ns: int, _exact: int = EXACT, _top: int = SUB_BITS + 1, _sub: int = SUB_BITS) -> None:
        """O(1), on the servo thread every tick (the constants are bound as locals: a global lookup each costs
        more than the arithmetic): the bucket is ``ns`` itself up to ``EXACT``, above it the top
        ``SUB_BITS + 1`` bits of ``ns`` after its octave's."""
        shift = (ns | _exact).bit_length() - _top
        self._counts[(shift << _sub) + (ns >> shift)] += 1
        if ns > self.max_ns:
            self.max_ns = ns

    @property
    def count(self) -> int:
        """Durations counted (summed: read for a summary, never per tick)."""
        return sum(self._counts)

    def percentile_ns(self, q: float) -> float:
        """The ``q`` th percentile [ns]: the middle of the bucket that holds the duration of that rank, never above
        the largest duration counted (a bucket's durations may all sit at its bottom)."""
        cumulative = np.cumsum(self._counts)
        bucket = np.searchsorted(cumulative, q / 100 * (cumulative[-1] - 1), side="right")
        low, width = _bucket_bounds(bucket)
        return float(min(low + (width - 1) / 2, self.max_ns))

    def summary_us(self) -> dict:
        """p50, p99 and max over the run [us]."""
        return {"p50": self.percentile_ns(50) * 1e-3, "p99": self.percentile_ns(99) * 1e-3, "max": self.max_ns * 1e-3}


class SlowCalls:
    """Why a call took over ``limit_ns`` of wall time: the calling thread's CPU time and context switches.

    ``before()`` reads the thread's CPU clock and ``getrusage(RUSAGE_THREAD)`` (under 1 µs, outside the
    call's timing); ``after`` reads them again for a slow call only. ``on_cpu``: the thread's CPU time
    alone is over the limit: the call's own work, or interrupts and hypervisor exits the host handled
    on the thread's time (on this VM a 1 µs row copy with nothing else to do reached 157 µs, all on the
    CPU). Else it was off the CPU: ``preempted`` (an involuntary switch: the OS ran something else),
    ``waited`` (a voluntary one: the GIL or a lock, which a call on the servo thread must never do), or
    ``unexplained`` (no switch the guest saw: on a VM, the hypervisor taking the CPU away, steal time).
    """

    def __init__(self, limit_ns: int = SLOW_NS):
        self.limit_ns = limit_ns
        self.counts = {"on_cpu": 0, "waited": 0, "preempted": 0, "unexplained": 0}

    def before(self) -> tuple:
        return resource.getrusage(resource.RUSAGE_THREAD), time.thread_time_ns()

    def after(self, began: tuple, wall_ns: int) -> None:
        if wall_ns <= self.limit_ns:
            return
        cpu_ns, usage = time.thread_time_ns() - began[1], resource.getrusage(resource.RUSAGE_THREAD)
        if cpu_ns > self.limit_ns:
            why = "on_cpu"
        elif usage.ru_nivcsw > began[0].ru_nivcsw:
            why = "preempted"
        elif usage.ru_nvcsw > began[0].ru_nvcsw:
            why = "waited"
        else:
            why = "unexplained"
        self.counts[why] += 1


class TickTiming:
    """Lateness, compute time and the recorder's cost per tick, over the whole run; overrun count."""

    def __init__(self, period_ns: int, explain_slow: bool = False):
        self.period_ns = int(period_ns)
        self._late, self._compute, self._recorder = _Durations(), _Durations(), _Durations()
        self.ticks = 0
        self.overruns = 0
        self.late_twice = 0  # ticks two or more periods late
        self.recorder_over_200us = 0
        self.recorder_slow = SlowCalls() if explain_slow else None  # why those were slow (wall time)
        self.new_overrun = False  # the last tick was an overrun (the loop raises the event)
        self.pauses = 0  # stretches of ticks that began after their deadline
        self.max_pause_ns = 0

    @property
    def max_late_ns(self) -> int:
        return self._late.max_ns

    def add(self, late_ns: int, compute_ns: int) -> None:
        self.ticks += 1
        self._late.add(late_ns)
        self._compute.add(compute_ns)
        self.new_overrun = late_ns >= self.period_ns
        if self.new_overrun:
            self.overruns += 1
            self.late_twice += late_ns >= 2 * self.period_ns

    def recorder(self, cost_ns: int, began: tuple | None = None) -> None:
        """What handing one tick to the recorder took on the servo thread [ns]; ``began``: what
        ``recorder_slow.before()`` read when the call began (wall time), so a call over 200 µs says why."""
        self._recorder.add(cost_ns)
        if cost_ns > SLOW_NS:
            self.recorder_over_200us += 1
            if began is not None:
                self.recorder_slow.after(began, cost_ns)

    def pause(self, pause_ns: int) -> None:
        """A stretch of ticks begins ``pause_ns`` after the deadline the last one left."""
        self.pauses += 1
        self.max_pause_ns = max(self.max_pause_ns, int(pause_ns))

    def summary(self) -> dict:
        """Period error, compute time and the recorder's servo-thread cost [us] (p50/p99/max over the
        run), overruns."""
        if self.ticks == 0:
            return {"ticks": 0, "overruns": 0}
        recorder = {}
        if self._recorder.count:
            cost = recorder["recorder_tick_us"] = {**self._recorder.summary_us(),
                                                   "over_200us": self.recorder_over_200us}
            if self.recorder_slow is not None:
                cost["over_200us_why"] = dict(self.recorder_slow.counts)
        return {**recorder, "ticks": self.ticks, "period_us": self.period_ns * 1e-3,
                "period_error_us": self._late.summary_us(), "compute_us": self._compute.summary_us(),
                "overruns": self.overruns, "later_than_two_periods": self.late_twice,
                "pauses_between_stretches": {"count": self.pauses, "max_ms": self.max_pause_ns * 1e-6}}
