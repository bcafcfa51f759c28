"""The servo thread's idle time, offered to the process's other Python work (the recorder's feeder).

Python threads share one interpreter lock. A thread that encodes and writes while a tick
computes, or when the servo thread wakes from its sleep, holds the lock the servo thread then
waits for (up to the switch interval, 50 µs, at every hand-over). Measured against sim-server at
1 kHz with a policy that does no work, 60 s each, alternating: period error p99 40 and 36 µs with
the writer running whenever it liked, 13 and 10 µs with this window. So the wall clock opens a
window while the servo thread sleeps (from the end of a tick's work to shortly before the next
deadline) and closes it when the servo thread wakes; the recorder's feeder thread (which pickles its
messages for the writer process, ``record.session``) starts a piece of work only inside
a window with time left for it. Outside a stretch of ticks (in simulated time; on wall time before a run's first
cycle and after its retreat) the window stays open; a run's cycles and retreat are one stretch, so a cycle's end
keeps it closed.
"""

from __future__ import annotations

import threading
import time

FOREVER = 2**63 - 1  # the window's end while the servo thread is not ticking [ns]


class IdleWindow:
    """``open(until_ns)`` by the servo thread before it sleeps, ``close()`` when it wakes; other threads
    ask ``time_left_ns()`` and wait for the next window with ``wait_next``."""

    def __init__(self):
        self.until_ns = FOREVER  # monotonic end of the open window; 0 while the servo thread computes
        self._opened = threading.Condition(threading.Lock())
        self._generation = 0  # windows opened so far

    def open(self, until_ns: int) -> None:
        with self._opened:
            self.until_ns = int(until_ns)
            self._generation += 1
            self._opened.notify_all()

    def close(self) -> None:
        self.until_ns = 0  # one store; readers only compare it

    def time_left_ns(self) -> int:
        return self.until_ns - time.monotonic_ns()

    def wait_next(self, timeout_s: float) -> None:
        """Until the next window opens, or ``timeout_s`` passes."""
        with self._opened:
            generation = self._generation
            self._opened.wait_for(lambda: self._generation != generation, timeout_s)
