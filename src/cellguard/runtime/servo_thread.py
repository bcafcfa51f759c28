"""What the servo thread asks of the OS and the interpreter while the wall-clock ticks run.

- ``SCHED_FIFO`` for the servo thread when the process may have it (root or CAP_SYS_NICE): a
  runnable real-time thread preempts every ordinary one, so a busy machine no longer delays a
  wake-up by a scheduler quantum. Refused: the loop runs as before, and says so (``scheduler``).
  The process's other Python threads (the recorder's feeder, inference worker) get the priority below:
  the servo thread waits for the GIL whoever holds it, and a holder preempted by an ordinary
  process would stall it for a whole quantum (priority inversion through the GIL).
  ``SCHED_RESET_ON_FORK`` keeps threads and processes started meanwhile (a policy process) ordinary.
- The cyclic garbage collector off, objects made before the ticks frozen out of it, and a young
  collection run only where a period has time to spare (``collect_if_idle``); a collection
  otherwise runs in whichever thread allocates, mid-tick.
- The clock's ``IdleWindow`` closed: other Python work waits for the servo thread's sleep.

Both are undone when the ticks stop (``ServoThread.__exit__``), so a test process or a CLI runs as
an ordinary thread again. A stretch may last a whole run (``WallClock.one_stretch``): a thread started
meanwhile (a CLI's progress display, started at the first cycle's end) is given the priority below at
the next young collection.
"""

from __future__ import annotations

import gc
import os
import threading

from cellguard.runtime.idle_window import FOREVER, IdleWindow

PRIORITY = 10  # SCHED_FIFO priority: above every ordinary thread, below the kernel's interrupt threads (50)
COLLECT_EVERY = 1000  # ticks between young collections [ticks]
COLLECT_SLACK_NS = 400_000  # a collection runs only when this much of the period is left [ns]


class ServoThread:
    """Context manager around the tick loop on the calling thread; ``scheduler`` says what it got."""

    def __init__(self, priority: int | None = PRIORITY, idle: IdleWindow | None = None):
        self.priority, self.idle = priority, idle
        self.scheduler = "other"
        self._previous: dict[int, tuple[int, os.sched_param]] = {}  # thread id (0: this one) -> policy, param
        self._gc_was_enabled = False
        self._ticks = 0
        self.active = False

    def __enter__(self) -> ServoThread:
        self.active = True
        self._promote()
        self._gc_was_enabled = gc.isenabled()
        gc.freeze()  # what exists now is not garbage: no collection walks it again
        gc.disable()
        self._ticks = 0
        if self.idle is not None:
            self.idle.close()
        return self

    def __exit__(self, *exc) -> None:
        if self._gc_was_enabled:
            gc.enable()
        gc.unfreeze()
        self._demote()
        self.active = False
        if self.idle is not None:
            self.idle.open(FOREVER)

    def collect_if_idle(self, slack_ns: int) -> None:
        """Called once per tick with the time left before the next deadline: collect the young
        generations every ``COLLECT_EVERY`` ticks if the period has room for it, and promote the
        threads started since the last time."""
        self._ticks += 1
        if self.active and self._ticks >= COLLECT_EVERY and slack_ns > COLLECT_SLACK_NS:
            self._ticks = 0
            gc.collect(1)
            if self.scheduler != "other":
                self._promote_others()

    def _promote(self) -> None:
        if self.priority is None or not hasattr(os, "SCHED_FIFO"):
            return
        if not self._set(0, self.priority):
            return  # not permitted here: ordinary threads, as before
        self.scheduler = f"fifo:{self.priority}"
        self._promote_others()

    def _promote_others(self) -> None:
        """The process's other Python threads not promoted yet: the priority below the servo thread's."""
        me, promoted = threading.get_ident(), self._previous
        for thread in threading.enumerate():
            if thread.ident != me and thread.native_id is not None and thread.native_id not in promoted:
                self._set(thread.native_id, max(1, self.priority - 1))

    def _set(self, tid: int, priority: int) -> bool:
        try:
            previous = (os.sched_getscheduler(tid), os.sched_getparam(tid))
            os.sched_setscheduler(tid, os.SCHED_FIFO | getattr(os, "SCHED_RESET_ON_FORK", 0),
                                  os.sched_param(priority))
        except OSError:  # PermissionError included; a thread that ended meanwhile
            return False
        self._previous[tid] = previous
        return True

    def _demote(self) -> None:
        for tid, (policy, param) in self._previous.items():
            try:
                os.sched_setscheduler(tid, policy, param)
            except OSError:  # a thread that ended meanwhile
                pass
        self._previous.clear()
