"""Clocks of the tick loop: simulated time that steps physics, or monotonic wall time.

``advance()`` ends one servo period. ``SimClock`` steps the cell's physics by one period and
never waits. ``WallClock`` sleeps until shortly before the next deadline, then spins to it
(``time.sleep`` alone wakes up to a scheduler quantum late); a simulated cell on wall time is
stepped once per period too. Each period's lateness and compute time go to ``TickTiming``.
``ticking()`` wraps a stretch of ticks (a cycle, a transition): on wall time the servo thread is a
real-time thread then, with the garbage collector run in idle time (``servo_thread``). Between
stretches (before a transition) the loop sends nothing and the robot holds its last setpoint; a
stretch that starts after its deadline starts a new period grid, and the pause is counted as such
(``TickTiming.pause``), not as a late tick. ``one_stretch()`` joins the stretches inside it (a run's
cycles): a cycle's end is then ticks on the same grid, its work counted in the next tick's compute
time, and a late tick or an overrun where that is over a period.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from contextlib import contextmanager, nullcontext

from cellguard.runtime.idle_window import IdleWindow
from cellguard.runtime.servo_thread import PRIORITY, ServoThread
from cellguard.runtime.timing import TickTiming

SWITCH_INTERVAL_S = 5e-5  # longest the servo thread waits for the GIL behind another Python thread [s]
SPIN_NS = 300_000  # the last stretch before a deadline is spun, not slept [ns]
SPIN_FIFO_NS = 100_000  # the same for a real-time servo thread, which wakes within tens of us [ns]


class SimClock:
    """Simulated time: ``now`` is the cell's time; ``advance`` steps its physics one period."""

    realtime = False

    def __init__(self, cell):
        self.period_ns = int(cell.dt_ns)
        self.timing = TickTiming(self.period_ns)
        self.now = lambda: cell.t_ns
        self.advance = cell.step

    def start(self) -> None:
        """Nothing to align in simulated time."""

    def ticking(self):
        """Simulated time asks nothing of the OS."""
        return nullcontext()

    def one_stretch(self):
        """Simulated time has no stretches to join."""
        return nullcontext()

    def regrid(self) -> None:
        """Simulated time has no grid to miss."""


class LockStepClock(SimClock):
    """A bridge's simulated robot that moves one period per command: ``now`` is the bridge's
    stamp, ``advance`` nothing (the write moved the robot); the loop never waits."""

    def __init__(self, robot):
        self.period_ns = int(robot.dt_ns)
        self.timing = TickTiming(self.period_ns)
        self.now = robot.clock
        self.advance = lambda: None  # the write has moved the robot one period already


class WallClock:
    """Monotonic wall time paced to ``period_ns``; ``step`` (if given) advances a simulated cell.

    ``now`` is the loop's time: the simulated cell's time when it steps one; else, inside a
    stretch of ticks, the time the tick in progress is scheduled for (a grid ``period_ns`` apart),
    and monotonic ns outside one. Not the wake-up: a reference sampled at wake-ups that jitter by
    tens of us moves by velocity x jitter, which the tracker's 1 ms finite differences read as
    tens of rad/s² (the guard then took over a smooth chunk on most ticks). A tick that ends later
    than one period past its deadline is an overrun: the next deadline is then taken from now
    (the loop never tries to catch up with a burst of short ticks).
    """

    realtime = True

    def __init__(self, period_ns: int, step: Callable[[], None] | None = None,
                 now: Callable[[], int] | None = None, spin_ns: int = SPIN_NS, priority: int | None = PRIORITY):
        self.period_ns, self._step, self._spin_ns = int(period_ns), step, int(spin_ns)
        self.timing = TickTiming(self.period_ns, explain_slow=True)
        self.now = now or self._scheduled
        self.priority = priority  # SCHED_FIFO priority while ticking (None: an ordinary thread)
        self.scheduler = "other"  # what the servo thread got the last time it ticked
        self.idle = IdleWindow()  # open while the servo thread sleeps: the recorder's feeder works then
        self._servo: ServoThread | None = None
        self._joined = False  # inside ``one_stretch``: a stretch once begun lasts to its end
        self._deadline = 0
        self._began = 0

    def start(self) -> None:
        """Align the first deadline one period from now.

        A Python thread holding the GIL (a pure-Python policy on the inference thread) keeps the
        servo thread waiting up to the interpreter's switch interval (5 ms by default); it is
        lowered to ``SWITCH_INTERVAL_S``. A quarter period was not enough: against sim-server with
        a pure-Python policy on a thread, period error p99 209 µs at 1 kHz and 1,213 µs at 200 Hz
        (300 s each), where 50 µs had given 10 and 72 µs.
        """
        sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL_S))
        self._began = time.monotonic_ns()
        self._deadline = self._began + self.period_ns

    def ticking(self):
        """A stretch of ticks runs inside this: the servo thread real-time and the collector in idle time.
        Inside a stretch already (a transition played by the cycle's first chunk), nothing changes."""
        if self._servo is not None and self._servo.active:
            return nullcontext(self._servo)
        self.regrid()
        self._servo = ServoThread(self.priority, self.idle)
        if self._joined:  # ended by ``one_stretch``
            return nullcontext(self._servo.__enter__())
        return self._servo

    @contextmanager
    def one_stretch(self):
        """The stretches of ticks begun inside this are one, from the first one's start to this one's end: the
        servo thread stays real-time, and the work between them (a cycle's end, about 0.5 ms at 1 kHz here) is no
        pause but part of the next tick on the same grid: a late tick or an overrun where it takes too long."""
        self._joined = True
        try:
            yield
        finally:
            self._joined = False
            if self._servo is not None and self._servo.active:
                self._servo.__exit__(None, None, None)

    def regrid(self) -> None:
        """A new period grid from now, the time past the last deadline counted as a pause, not as a late tick: at a
        stretch's start, and inside one after work that is no tick (the guard built anew where an approach left the
        robot, at rest: the cycle's next tick was 5 to 23 ms late, an overrun, and ``overrun_budget: 0`` stopped
        every run that needed an approach)."""
        now = time.monotonic_ns()
        if now > self._deadline:
            self.timing.pause(now - self._deadline)
        self._began, self._deadline = now, now + self.period_ns

    def _scheduled(self) -> int:
        """Inside a stretch: the time the tick in progress is scheduled for; outside: monotonic ns."""
        if self._servo is not None and self._servo.active:
            return self._deadline - self.period_ns
        return time.monotonic_ns()

    def advance(self) -> None:
        """Step (a simulated cell), then wait for the deadline; account lateness and compute time."""
        if self._step is not None:
            self._step()
        clock = time.monotonic_ns
        compute = clock() - self._began
        deadline = self._deadline
        servo, spin = self._servo, self._spin_ns
        ticking = servo is not None and servo.active
        if ticking:
            servo.collect_if_idle(deadline - clock())
            self.scheduler = servo.scheduler
            if servo.scheduler != "other":
                spin = min(spin, SPIN_FIFO_NS)
        left = deadline - clock() - spin
        if left > 0:
            if ticking:  # outside a stretch (a stop's settling time) the window stays open for good
                self.idle.open(deadline - spin)
            time.sleep(left * 1e-9)
            if ticking:
                self.idle.close()
        while clock() < deadline:
            pass
        woke = clock()
        late = woke - deadline
        self.timing.add(late, compute)
        self._began = woke
        self._deadline = deadline + self.period_ns if late < self.period_ns else woke + self.period_ns
