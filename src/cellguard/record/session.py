"""The recorder as the tick loop uses it: fed by the loop, written by a process of its own.

The loop's thread copies each tick into the pre-trigger ring (``record.ring``), which lives in
memory shared with a writer process forked at the start: a few microseconds, no allocation, no
lock. Everything else happens in the writer process, on another core: CDR and JSON encoding,
zstd, the MCAP chunks, fsync, the index. The other calls (chunks, measurements, events, context,
cycle ends) reach it as messages, each stamped with the number of ticks added before it, so the
writer takes them between the same ticks as the loop made them. A writer *thread* shared the
interpreter lock with the loop: in simulated time the two took turns (10 demo cycles 9 to 28 %
slower than writing on the loop's thread), and on wall time its fsync and encoding returned mid-tick
and took the lock back (recorder calls of 200 to 250 µs on the servo thread).

The loop may run ``queue_s`` of ticks ahead of the writer. On wall time a tick past that is not
recorded: it is counted and a ``record_queue_full`` event is raised (once per episode); the
servo thread never blocks. In simulated time no tick has a deadline, so the loop waits for the
writer instead and nothing is dropped. The durability policy is the recorder's either way
(chunks and fsync by tick time). The writer takes the ring's ticks only when a message tells it
to: every ``_every`` ticks (a chunk's worth, at most half the queue) and with each cycle's end,
so the ring holds up to that many ticks even for a writer that keeps up (``high_water``).
``writer_lag`` is the longest the writer took to take ticks after it was told to [ticks]: the
feeder's wait for an idle window, the pipe and the writer's own work, not the batching.

A write error, or any fault inside the recorder, ends the recording for good: the writer raises a
flag in the shared memory, the loop reads it after each tick and stops the cell (category 2,
``record_failed``), because an unrecorded run is not allowed. A writer process that dies counts
the same. When the loop's process dies (SIGKILL, out of memory), the writer takes the ticks already
in the ring, records a ``run_process_lost`` event and finishes the file, so a crash loses at most
the messages not yet sent (a few ticks' worth) instead of the open chunk, and the record says the
run did not end. Ctrl-C, SIGTERM and SIGHUP reach the writer too (a terminal or a service manager
signals the whole process group): it ignores them and finishes when the loop, which stops the cell on
them and retreats, closes the recording. Finishing on SIGTERM itself closed the file in the
feeder's first pause on wall time, before the stop and the retreat were recorded.

What the process holds at the start (the cell's model, the modules, the run) is frozen out of the
garbage collector (``gc.freeze``): a collection holds the interpreter lock from start to end, and
with the whole heap to traverse one took up to tens of milliseconds under load.

The writer is a forked process (POSIX): it inherits the open record and the ring, nothing is
pickled but the messages. On wall time the loop's process then copies the pages it still shares
with the writer before the first tick (``shared_pages``), so no tick takes a copy-on-write fault.
"""

from __future__ import annotations

import atexit
import collections
import errno
import gc
import mmap
import multiprocessing
import os
import pickle
import signal
import threading
import time
from multiprocessing.connection import wait
from pathlib import Path

from cellguard.control.events import Event, EventKind
from cellguard.errors import RecordError
from cellguard.record import folder_lock
from cellguard.record.context import build_context, software_versions
from cellguard.record.index import default_opener
from cellguard.record.json_values import MAX_DEPTH, deeper, plain
from cellguard.record.shared_pages import copy_shared_pages
from cellguard.record.urdf import describe
from cellguard.record.writer import RECORD_FILE, RecordConfig, Recorder, refuse_existing
from cellguard.threads import start_thread

POLL_S = 0.002  # how often the writer checks the loop's process, and the feeder and the loop's waits poll [s]
WRITER_NICE = 10  # the writer process yields the CPU to the loop and the policy
WINDOW_MARGIN_NS = 150_000  # the feeder sends a batch only with this much of the servo thread's sleep left
CLOSE_TIMEOUT_S = 60.0  # longest wait for the writer to finish the file at close [s]
RESERVE_BYTES = (256 << 10, 8 << 10)  # disk kept free for summary.json: base + per cycle, released at close [bytes]
RESERVE_FILE = ".cellguard-reserve"
PICKLE = pickle.HIGHEST_PROTOCOL  # plain pickle: multiprocessing's own pickler is several times slower here
HEAD, TAIL, FAILED = 0, 1, 2  # shared counters: ticks added by the loop, ticks taken by the writer, writer failed


class RunRecording:
    """One run's record: context per cycle, measurements, chunks, ticks, events, cycle ends."""

    def __init__(self, recorder: Recorder, run, reserve: Path | None = None, lock: int | None = None):
        self.run, self.name = run, recorder.name
        self._lock = lock  # the folder's lock (``folder_lock``), shared with the writer process, let go at close
        self.failed: str | None = None
        self.finished = False  # the writer finished the file and the index at close, without an error
        self.dropped = 0  # ticks not recorded because the writer was queue_s behind (wall time)
        self.high_water = 0  # most ticks in the ring not taken yet (up to ``_every`` not told of yet)
        self.writer_lag = 0  # longest the writer took to take ticks after it was told to [ticks]
        self._told = 0  # the ticks the writer has been told to take: the ring's count at the last batch sent
        self._caught_up = 0  # the ring's count at the last tick when the writer had taken all it was told to
        self._events_seen = len(run.events)
        self._software = software_versions()
        self._config = recorder.config
        self._cycle = 0  # the cycle begun last: each tick's stamp
        self._begun_ns: int | None = None  # its begin [ns]; None before the first
        self._ring = ring = recorder.ring  # made shared (``Recorder``'s ``slack``) by ``start``
        self._slack = ring.capacity - ring.keep
        # ticks between "take the ticks" messages: a chunk's worth, and often enough that the writer hears of a
        # tick well before the loop could run a queue ahead of it
        self._every = max(1, min(recorder.config.chunk_ns // recorder.dt_ns, self._slack // 2))
        self._ctl = memoryview(mmap.mmap(-1, 3 * 8)).cast("q")
        self._full = False
        self._reserve = reserve
        self._realtime = run.clock.realtime
        self._outbox: collections.deque = collections.deque()  # appended by the loop, emptied by the sender
        self._feeder = None
        context = multiprocessing.get_context("fork")
        op_reader, self._op_writer = context.Pipe(duplex=False)
        self._replies, reply_writer = context.Pipe(duplex=False)
        self._process = context.Process(target=_serve, name="cellguard-recorder", daemon=True,
                                        args=(recorder, self._ctl, op_reader, self._op_writer, reply_writer, reserve))
        gc.freeze()  # until close, which hands it all back to the collector (garbage frozen now included)
        try:
            self._process.start()
        except BaseException:  # no process forked (EAGAIN, ENOMEM)
            gc.unfreeze()
            raise
        op_reader.close()
        reply_writer.close()
        # a process ending without close (Ctrl-C in a caller with no stop handler: bench) joins its daemon children
        # at exit, and the writer, deaf to SIGTERM, waits for the end of this pipe: ended first, it finishes the
        # file as a lost loop's and ends (else the process hung until the writer was killed)
        atexit.register(self._op_writer.close)
        try:
            # wall time: the writes that would copy the pages now shared with the writer, done now, not mid-tick
            self.pages_copied = copy_shared_pages() if self._realtime else None
            if self._realtime:
                feeder = threading.Thread(target=self._feed, name="cellguard-record-feeder", daemon=True)
                refused = start_thread(feeder)
                if refused is not None:
                    raise RecordError(f"{self.name}: cannot start the record ({refused}); nothing was run")
                self._feeder = feeder  # started: ``close`` sends through it and joins it
            recorder.place()  # the old record, if any, stays whole until now
        except BaseException:  # the writer, told to end, discards the record never placed; the lock is start's
            self.close(keep_folder=True)
            raise

    @classmethod
    def start(cls, folder: Path, run, config: RecordConfig = RecordConfig(), opener=default_opener,
              replace: bool = False, queue_s: float = 2.0, lock: int | None = None) -> RunRecording:
        """Open the record of ``run`` in ``folder``; RecordError (nothing runs) if it cannot be written.

        Refused if ``folder`` holds a record already, unless ``replace``, and if another run is writing there
        (``folder_lock``), even with ``replace``. A record replaced stays whole until the new one has started, its
        writer process included (``Recorder.place``): a start that fails before leaves it as it was. A small reserve
        file keeps room for ``summary.json`` on a disk that fills up during the run; a disk without room for it is
        refused here, since a run without one could end with a record and no summary. ``lock``: the folder's lock,
        held already by a caller that writes more beside the record (the demo's report); it is the caller's to let go.
        """
        folder = Path(folder)
        refuse_existing(folder, replace)  # before anything is written there
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise RecordError(f"{folder / RECORD_FILE}: cannot start the record ({exc.strerror or exc}); nothing "
                              f"was run") from None
        # a report writing beside a record holds the folder a moment: waited on
        held = lock if lock is not None else folder_lock.hold(folder, wait_s=folder_lock.BRIEF_S)
        owned = None if lock is not None else held
        reserve = recorder = None
        try:
            refuse_existing(folder, replace)  # again under the lock: a run that just finished there has a record
            cycles = getattr(run.scenario, "total_cycles", 100)
            context = cls._context(run, config, software_versions())
            _refuse_deep(context, folder)
            profile = run.cell.profile
            model = getattr(run.cell, "model", None)
            description = None if model is None else describe(model, profile)
            reserve = _reserve(folder / RESERVE_FILE, RESERVE_BYTES[0] + RESERVE_BYTES[1] * cycles)  # else nothing runs
            # the ring made once, in memory shared with the writer process, ``queue_s`` of ticks ahead of it
            recorder = Recorder.create(folder, joints=profile.joint_names, dt_ns=run.cell.dt_ns, context=context,
                                       config=config, opener=opener, description=description, replace=replace,
                                       start_ns=run.clock.now(),  # wall time: the monotonic clock
                                       slack=max(1, round(queue_s * 1e9 / run.cell.dt_ns)), place=False)
            return cls(recorder, run, reserve=reserve, lock=owned)  # places the record once its writer runs
        except BaseException as exc:
            if recorder is not None:
                recorder.discard()
            _release(reserve)
            folder_lock.release(owned)
            if isinstance(exc, (MemoryError, OSError)):  # the ring or the writer process could not be made
                why = getattr(exc, "strerror", None) or str(exc) or "out of memory"
                raise RecordError(f"{folder / RECORD_FILE}: cannot start the record ({type(exc).__name__}: {why}); "
                                  f"nothing was run") from None
            raise

    @staticmethod
    def _context(run, config: RecordConfig, software: dict, cycle: int = 0) -> dict:
        """The run's context; ``process``: the process changes declared by ``cycle`` (undeclared ones stay out)."""
        context = build_context(scenario=run.scenario, cell=run.cell, policy=run.policy, envelope=run.guard.envelope,
                                software=software)
        release = getattr(run, "release", None)  # set by cellguard.release: the release and any pointer switch
        return {**context, **({"release": release} if release else {}), "record": config.to_dict(),
                "process": run.scenario.declared_process(cycle)}

    # -- the loop's thread ---------------------------------------------------------------------
    def begin_cycle(self, cycle: int, phase: str, t_ns: int) -> None:
        self.events()  # raised before this begin: not in this cycle
        self._cycle, self._begun_ns = cycle, t_ns
        self._put("set_context", self._context(self.run, self._config, self._software, cycle), t_ns)
        self._put("cycle_begin", cycle, phase, t_ns)

    def request(self, t_ns: int, observation) -> None:
        self._put("measurements", t_ns, self._cycle, observation.measurements)

    def chunk(self, chunk, t_ns: int, latency_ns: int) -> None:
        self._put("chunk", chunk, t_ns, latency_ns)

    def tick(self, t_ns: int, reference, sent, state) -> bool:
        """Put the tick of loop time ``t_ns`` in the shared ring (wall time: never blocks) and queue any new
        events; False once recording has failed. The tick's time is the loop's, as its events' are: a bridge's
        state stamp repeats when no new packet came, and the reader took those ticks for copies (2 % of a
        sim-server run's ticks lost, and the setpoint steps across them read as twice the speed limit)."""
        if len(self.run.events) > self._events_seen:
            self.events()
        ring, ctl = self._ring, self._ctl
        tail = ctl[TAIL]
        if tail >= self._told:
            self._caught_up = ring.n
        elif ring.n - self._caught_up > self.writer_lag:
            self.writer_lag = ring.n - self._caught_up
        waiting = ring.n - tail
        if waiting >= self._slack:
            if self._realtime:
                return self._drop(t_ns, waiting)
            if not self._wait_for_writer():
                return False
        elif waiting > self.high_water:
            self.high_water = waiting
        self._full = False
        ring.add(t_ns, self._cycle, reference, sent, state.q, state.qd, state.effort, state.current)
        ctl[HEAD] = ring.n
        if ring.n % self._every == 0:
            self._send("")  # the writer takes ticks when told, so every message stays between its ticks
        if ctl[FAILED]:  # raised by the writer, or by the sender when the writer's pipe broke
            return self._writer_failed()
        return self.failed is None

    def end_cycle(self, outcome: dict, t_ns: int) -> None:
        self.events()
        self._send("cycle_end", outcome, t_ns)

    def events(self) -> None:
        """Queue the run's events not recorded yet, each with the cycle begun last if it is not before that cycle's
        begin, else with none (before the first cycle); one queued after the cycle's end lies in none (the
        recorder's ``event``: the retreat's were the last cycle's)."""
        events, begun = self.run.events, self._begun_ns
        for event in events[self._events_seen:]:
            inside = begun is not None and begun <= event.t_ns
            self._put("event", event, self._cycle if inside else None)
        self._events_seen = len(events)

    def close(self, keep_folder: bool = False) -> None:
        """Let the writer take what is queued and finish the file (after a failure only the handle is
        closed); free the reserve; let go of the folder unless ``keep_folder`` (``release_folder`` does, once the
        summary is beside the record: written after, it could land in the folder of a run started in between)."""
        atexit.unregister(self._op_writer.close)
        self.events()
        self._send(None)
        if self._feeder is not None:
            self._feeder.join()
        try:
            reply = self._reply(CLOSE_TIMEOUT_S)
            if reply is not None:
                self.failed = self.failed or reply
            self.finished = self.failed is None
        finally:
            self._process.join(CLOSE_TIMEOUT_S)
            self._replies.close()
            gc.unfreeze()
            _release(self._reserve)
            if not keep_folder:
                self.release_folder()

    def release_folder(self) -> None:
        """Let go of the folder's lock (the writer process, joined, held it too)."""
        folder_lock.release(self._lock)
        self._lock = None

    def _put(self, name: str | None, *args) -> None:
        """A message for the writer, sent with the next batch: take the ticks added so far, then call recorder
        method ``name`` (``""``: none; ``None``: finish the file and end)."""
        self._outbox.append((self._ring.n, name, args))

    def _send(self, name: str | None, *args) -> None:
        """Send the batch with this message last: on wall time through the feeder thread (the servo thread never
        waits on the pipe), in simulated time from the loop's thread (no second thread taking turns with it)."""
        self._put(name, *args)
        self._told = self._ring.n
        if self._feeder is not None:
            return
        batch = list(self._outbox)
        self._outbox.clear()
        self._deliver(batch)
        if name is None:
            self._op_writer.close()

    def _deliver(self, batch: list) -> bool:
        """Pickle and send ``batch``; a broken pipe (the writer died) raises the failed flag; False then."""
        try:
            self._op_writer.send_bytes(pickle.dumps(batch, PICKLE))
        except OSError:
            self._ctl[FAILED] = 1
            return False
        return True

    def _drop(self, t_ns: int, waiting: int) -> bool:
        self.dropped += 1
        if not self._full:
            self._full = True
            self.run.events.append(Event(t_ns, EventKind.RECORD_QUEUE_FULL,
                                         f"the recorder is {waiting} ticks behind; ticks are dropped "
                                         f"until the writer catches up"))
        return self.failed is None

    def _wait_for_writer(self) -> bool:
        """Simulated time: wait until the writer has room again; False if it failed or died meanwhile."""
        while self._ring.n - self._ctl[TAIL] >= self._slack:
            if self._ctl[FAILED] or not self._process.is_alive():
                return self._writer_failed()
            time.sleep(POLL_S / 4)
        return True

    def _writer_failed(self) -> bool:
        """The writer raised its flag or ended: why, once; False."""
        if self.failed is None:
            if self._ctl[FAILED]:
                self.failed = self._reply(CLOSE_TIMEOUT_S) or f"{self.name}: recording failed"
            else:
                self.failed = f"{self.name}: the recorder process ended (exit code {self._process.exitcode})"
        return False

    def _reply(self, timeout_s: float) -> str | None:
        """The writer's next reply (why it failed, or at close its final word); a dead writer says why it
        cannot answer."""
        end = time.monotonic() + timeout_s
        while not self._replies.poll(POLL_S):
            if not self._process.is_alive() and not self._replies.poll():
                return f"{self.name}: the recorder process ended (exit code {self._process.exitcode})"
            if time.monotonic() > end:
                return f"{self.name}: the recorder process did not answer in {timeout_s:.0f} s"
        try:
            return self._replies.recv()
        except EOFError:
            return f"{self.name}: the recorder process ended (exit code {self._process.exitcode})"

    # -- the feeder thread (wall time): pickles and sends the messages in the servo thread's idle window
    # (``runtime.idle_window``), so that the servo thread never waits on the pipe, nor long for the GIL
    def _feed(self) -> None:
        """Each time the servo thread goes to sleep (and every ``POLL_S`` outside a stretch of ticks), send what
        it queued if the window has room for it; never woken by the servo thread itself."""
        outbox, idle = self._outbox, self.run.clock.idle
        try:
            while True:
                idle.wait_next(POLL_S)
                if not outbox or idle.time_left_ns() < WINDOW_MARGIN_NS:
                    continue
                batch = []
                while outbox:  # popleft, not a swap: the servo thread may append meanwhile
                    batch.append(outbox.popleft())
                if not self._deliver(batch) or batch[-1][1] is None:
                    return
        finally:
            self._op_writer.close()


# -- the writer process ------------------------------------------------------------------------
def _serve(recorder: Recorder, ctl, ops, op_writer, replies, reserve: Path | None) -> None:
    """The writer process: messages in order, the ring's ticks between them, until told to finish or
    the loop's process is gone (then the record says so, and the reserve the loop would free goes too)."""
    op_writer.close()  # the loop's end only: a loop that dies mid-message then reads as the end of the pipe
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the loop stops the cell on these and then closes the recording
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    signal.signal(signal.SIGHUP, signal.SIG_IGN)  # a closed terminal's, to the whole group: a stop for the loop too
    try:
        os.nice(WRITER_NICE)
    except OSError:
        pass
    parent = multiprocessing.parent_process().sentinel
    failed: list[str] = []

    def apply(fn, *args) -> None:
        if failed:
            return
        try:
            fn(*args)
        except RecordError as exc:
            failed.append(str(exc))
        except Exception as exc:  # noqa: BLE001
            failed.append(f"{recorder.name}: recorder fault ({type(exc).__name__}: {exc})")
        if failed:
            replies.send(failed[0])
            ctl[FAILED] = 1

    while True:
        ready = wait([ops, parent], POLL_S)
        lost = False
        if ops in ready:
            try:
                batch = pickle.loads(ops.recv_bytes())
            except EOFError:  # the pipe closed before the end was sent: the loop's process died
                lost = True
        elif parent in ready:  # the loop's process is gone: what it put in the ring is all there is
            lost = True
        else:
            continue
        if lost:
            batch = [(ctl[HEAD], None, ())]
            if recorder.placed:  # else the start was killed: no run, so nothing to say
                batch.insert(0, (ctl[HEAD], "run_lost", ("the run's process ended without finishing the run (killed, "
                                                         "or out of memory); the ticks it had handed over are "
                                                         "recorded",)))
        for n, name, args in batch:
            apply(recorder.advance, n)
            ctl[TAIL] = n
            if name is None:
                try:  # a record never placed (the start failed after the fork): removed, the one it replaces whole
                    recorder.close() if recorder.placed else recorder.discard()
                except Exception as exc:  # noqa: BLE001 (a RecordError, or a fault: the handle is closed either way)
                    failed.append(str(exc) if isinstance(exc, RecordError) else
                                  f"{recorder.name}: recorder fault ({type(exc).__name__}: {exc})")
                if lost:
                    _release(reserve)
                replies.send(failed[0] if failed else None)
                return
            if name:
                apply(getattr(recorder, name), *args)


def _reserve(path: Path, size: int) -> Path:
    """Set ``size`` bytes aside in ``path``; RecordError (nothing left behind) if the disk has not even that."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        try:
            _allocate(fd, size)
        finally:
            os.close(fd)
    except OSError as exc:
        _release(path)
        raise RecordError(f"{path.parent / RECORD_FILE}: cannot start the record (cannot set aside the "
                          f"{size // 1024} KB kept free for summary.json: {exc.strerror or exc}); nothing was run"
                          ) from None
    return path


def _allocate(fd: int, size: int) -> None:
    """Allocate ``size`` bytes of ``fd``: posix_fallocate, or zeros written where the filesystem lacks it."""
    try:
        os.posix_fallocate(fd, 0, size)
        return
    except AttributeError:  # not on this platform
        pass
    except OSError as exc:
        if exc.errno not in (errno.EOPNOTSUPP, errno.ENOTSUP, errno.EINVAL, errno.ENOSYS):
            raise
    block = bytes(64 << 10)
    for start in range(0, size, len(block)):
        os.write(fd, block[:size - start])
    os.fsync(fd)


def _release(path: Path | None) -> None:
    if path is not None:
        try:
            path.unlink()
        except OSError:
            pass


def _refuse_deep(context: dict, folder: Path) -> None:
    """RecordError, before anything runs, naming the first key of ``context`` whose value nests past what a reader
    takes (``json_values.MAX_DEPTH``: a cell's or plugin's own description 150 deep was written, and the run's own
    record then read as damaged, its context lost)."""
    # the context message holds the context, which holds the value: two levels above it
    deep = next((key for key, value in context.items() if deeper(plain(value), MAX_DEPTH - 2)), None)
    if deep is not None:
        raise RecordError(f"{folder / RECORD_FILE}: the run's context nests {deep!r} deeper than {MAX_DEPTH} levels, "
                          f"which no reader of the record takes (a cell's or plugin's own description?); nothing was "
                          f"run")
