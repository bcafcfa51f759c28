"""The recorder as the tick loop uses it: on wall time fed from the servo thread and written on a
thread of its own; in simulated time written on the loop's thread.

On wall time the servo thread only appends to a bounded queue (a copy of the reference and the
setpoint, the measured state as read, about a microsecond); the writer thread does everything
else: the pre-trigger ring, CDR and JSON encoding, zstd, the MCAP chunks, fsync, the index. A full
queue never blocks the servo thread: the tick is dropped, counted, and a ``record_queue_full``
event is raised (once per episode). While the writer thread runs, the interpreter's switch interval
is lowered to ``SWITCH_INTERVAL_S`` so that the servo thread never waits long for the GIL, and the
writer works only while the servo thread sleeps: the clock's ``idle`` window
(``runtime.idle_window``) says until when, and a piece of work (a tick, a chunk flush) starts only
with ``WINDOW_MARGIN_NS`` of it left, unless the queue is half full (then losing ticks is worse
than a late tick).

In simulated time no tick has a deadline, so the loop's own thread calls the recorder directly: no
tick is ever dropped, and the run does not pay for two threads taking turns with the GIL (a writer
thread made 10 demo cycles take 9 to 28 % longer, alternating runs: it took the GIL whenever MuJoCo's
step released it).
The durability policy is the recorder's either way (chunks and fsync by tick time).

A write error ends the recording for good and sets ``failed``; the loop reads it after each tick
and stops the cell (category 2, ``record_failed``) because an unrecorded run is not allowed. What
the process holds at the start (the cell's model, the modules, the run) is frozen out of the
garbage collector (``gc.freeze``): a collection holds the GIL from start to end, whichever thread
runs it, and with the whole heap to traverse one took up to tens of milliseconds under load.

On wall time a crash loses what is still queued (at most ``queue_s`` of ticks) on top of the open chunk.
"""

from __future__ import annotations

import collections
import gc
import os
import sys
import threading
from pathlib import Path

from cellguard.control.events import Event, EventKind
from cellguard.errors import RecordError
from cellguard.record.context import build_context, software_versions
from cellguard.record.index import default_opener
from cellguard.record.urdf import describe
from cellguard.record.writer import RecordConfig, Recorder, refuse_existing

SWITCH_INTERVAL_S = 5e-5  # longest GIL hold the servo thread may wait for behind the writer [s]
POLL_S = 0.002  # the writer thread looks at the queue at least this often [s]
WINDOW_MARGIN_NS = 150_000  # the writer starts a piece of work only with this much of the servo's sleep left
RESERVE_BYTES = (256 << 10, 8 << 10)  # disk kept free for summary.json: base + per cycle, released at close [bytes]
RESERVE_FILE = ".cellguard-reserve"


class RunRecording:
    """One run's record: context per cycle, measurements, chunks, ticks, events, cycle ends."""

    def __init__(self, recorder: Recorder, run, queue_s: float = 2.0, reserve: Path | None = None):
        self.recorder, self.run = recorder, run
        self.failed: str | None = None
        self.dropped = 0  # ticks not recorded because the queue was full
        self.high_water = 0  # most ticks waiting at once
        self._events_seen = len(run.events)
        self._software = software_versions()
        self._cycle = 0
        self._capacity = max(1, round(queue_s * 1e9 / recorder.dt_ns))
        self._queued = 0  # ticks put on the queue (servo thread)
        self._written = 0  # ticks taken off it (writer thread)
        self._full = False
        self._ops: collections.deque = collections.deque()
        self._wake = threading.Event()
        self._reserve = reserve
        self._tick = recorder.tick
        self._switch = sys.getswitchinterval()
        gc.freeze()  # until close, which hands it all back to the collector (garbage frozen now included)
        self._thread = None  # simulated time: none, the loop's thread writes and nothing is dropped
        if run.clock.realtime:
            sys.setswitchinterval(min(self._switch, SWITCH_INTERVAL_S))
            self._thread = threading.Thread(target=self._drain, name="cellguard-recorder", daemon=True)
            self._thread.start()

    @classmethod
    def start(cls, folder: Path, run, config: RecordConfig = RecordConfig(), opener=default_opener,
              replace: bool = False, queue_s: float = 2.0) -> RunRecording:
        """Open the record of ``run`` in ``folder``; RecordError (nothing runs) if it cannot be written.

        Refused if ``folder`` holds a record already, unless ``replace``. A small reserve file keeps
        room for ``summary.json`` on a disk that fills up during the run.
        """
        folder = Path(folder)
        refuse_existing(folder, replace)  # before anything is written there
        cycles = getattr(run.scenario, "total_cycles", 100)
        reserve = _reserve(folder / RESERVE_FILE, RESERVE_BYTES[0] + RESERVE_BYTES[1] * cycles)
        context = cls._context(run, config, software_versions())
        profile = run.cell.profile
        model = getattr(run.cell, "model", None)
        description = None if model is None else describe(model, profile.joint_names, profile.robot)
        try:
            recorder = Recorder.create(folder, joints=profile.joint_names, dt_ns=run.cell.dt_ns, context=context,
                                       config=config, opener=opener, description=description, replace=replace)
        except RecordError:
            _release(reserve)
            raise
        return cls(recorder, run, queue_s=queue_s, reserve=reserve)

    @staticmethod
    def _context(run, config: RecordConfig, software: dict, cycle: int = 0) -> dict:
        """The run's context; ``process``: the process changes declared by ``cycle`` (undeclared ones stay out)."""
        context = build_context(scenario=run.scenario, cell=run.cell, policy=run.policy, envelope=run.guard.envelope,
                                software=software)
        release = getattr(run, "release", None)  # set by cellguard.release: the release and any pointer switch
        return {**context, **({"release": release} if release else {}), "record": config.to_dict(),
                "process": run.scenario.declared_process(cycle)}

    # -- servo thread ------------------------------------------------------------------------
    def begin_cycle(self, cycle: int, phase: str, t_ns: int) -> None:
        self._cycle = cycle
        self._put(self.recorder.set_context, self._context(self.run, self.recorder.config, self._software, cycle), t_ns)
        self._put(self.recorder.cycle_begin, cycle, phase, t_ns)

    def request(self, t_ns: int, observation) -> None:
        self._put(self.recorder.measurements, t_ns, self._cycle, observation.measurements)

    def chunk(self, chunk, t_ns: int, latency_ns: int) -> None:
        self._put(self.recorder.chunk, chunk, t_ns, latency_ns)

    def tick(self, reference, sent, state) -> bool:
        """Record (simulated time) or queue (wall time, never blocks) the tick and any new events; False
        once recording has failed."""
        if len(self.run.events) > self._events_seen:
            self.events()
        if self._thread is None:
            self._apply(self._tick, (self._cycle, reference, sent, state))
            return self.failed is None
        waiting = self._queued - self._written
        if waiting > self.high_water:
            self.high_water = waiting
        if waiting >= self._capacity:
            self.dropped += 1
            if not self._full:
                self._full = True
                self.run.events.append(Event(state.t_ns, EventKind.RECORD_QUEUE_FULL,
                                             f"the recorder queue holds {waiting} ticks; ticks are dropped "
                                             f"until the writer catches up"))
            return self.failed is None
        self._full = False
        self._ops.append((self._tick, (self._cycle, reference.copy(), sent.copy(), state)))
        self._queued += 1
        return self.failed is None

    def end_cycle(self, outcome: dict, t_ns: int) -> None:
        self.events()
        self._put(self.recorder.cycle_end, outcome, t_ns)

    def events(self) -> None:
        """Queue the run's events not recorded yet."""
        events = self.run.events
        for event in events[self._events_seen:]:
            self._put(self.recorder.event, event, self._cycle)
        self._events_seen = len(events)

    def close(self) -> None:
        """Write what is queued, finish the file (after a failure only the handle is closed), free the reserve."""
        self.events()
        if self._thread is not None:
            self._ops.append((None, ()))
            self._wake.set()
            self._thread.join()
            sys.setswitchinterval(self._switch)
        gc.unfreeze()
        try:
            self.recorder.close()
        except RecordError as exc:
            self.failed = self.failed or str(exc)
        finally:
            _release(self._reserve)

    def _put(self, fn, *args) -> None:
        if self._thread is None:
            self._apply(fn, args)
        else:
            self._ops.append((fn, args))

    def _apply(self, fn, args) -> None:
        """One piece of recorder work; a fault of any kind stops the recording (and so the cell), never the loop."""
        if self.failed is not None:
            return
        try:
            fn(*args)
        except RecordError as exc:
            self.failed = str(exc)
        except Exception as exc:  # noqa: BLE001
            self.failed = f"{self.recorder.name}: recorder fault ({type(exc).__name__}: {exc})"

    # -- writer thread -----------------------------------------------------------------------
    def _drain(self) -> None:
        ops, tick = self._ops, self._tick
        idle = self.run.clock.idle
        while True:
            while ops:
                if (idle.time_left_ns() < WINDOW_MARGIN_NS
                        and self._queued - self._written < self._capacity // 2):
                    idle.wait_next(POLL_S)  # the servo thread computes, or wakes soon: not now
                    continue
                fn, args = ops.popleft()
                if fn is None:
                    return
                self._apply(fn, args)
                if fn is tick:
                    self._written += 1
            self._wake.wait(POLL_S)
            self._wake.clear()


def _reserve(path: Path, size: int) -> Path | None:
    """Set ``size`` bytes aside in ``path``; None (no reserve) if the disk has not even that."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        try:
            os.posix_fallocate(fd, 0, size)
        finally:
            os.close(fd)
    except OSError:
        _release(path)
        return None
    return path


def _release(path: Path | None) -> None:
    if path is not None:
        try:
            path.unlink()
        except OSError:
            pass
