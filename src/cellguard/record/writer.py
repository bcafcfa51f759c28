"""The recorder: every tick, chunk, event and cycle of a run, written so that a crash loses little.

Record format version 2 (version 1 is still read): log and publish times are the wall clock at
the run clock's zero plus the run's clock (``epoch_wall_ns + t_ns``, integer ns; the payloads
keep ``t_ns``), so viewers show the real date and time. A run clock that does not start at zero
(wall time reads the monotonic clock, counted from boot) gives ``start_ns``: the record starts
there, and the epoch is the wall clock at the start less ``start_ns`` (it was the start itself,
and every tick showed late by the host's uptime); a ``foxglove`` metadata record names the device
(site / cell id) and a ``cellguard`` one the context's key facts; next to cellguard's own tick
batches, every kept tick is also a ROS 2 ``sensor_msgs/msg/JointState``, the moving joints' poses
go on ``/tf``, events also go on ``/events/log`` (``rcl_interfaces/msg/Log``), and the robot's URDF
is an attachment and a ``/robot_description`` message. Messages go to the file in log-time order:
each chunk's messages are sorted before it is closed, and a pre-trigger backlog that reaches back
before what is already written keeps its true time in ``publish_time`` and in its payload
(``t_ns``, ``header.stamp``) but is logged at the time it was written. The context is repeated
every ``context_every_s`` and, at close, as a metadata record, so a damaged first chunk does not
take it away.

Durability policy (see the README, "Fault record"):

* Each servo tick is copied into the pre-trigger ring (no I/O). Every ``chunk_ns`` of ticks
  (100 ms by default) the recorder writes the decimated ticks and any full-rate window, closes the
  MCAP chunk (CRC on) and hands it to the operating system: a process crash (SIGKILL) loses at most
  the open chunk, i.e. ``chunk_ns`` of ticks and the events raised in it.
* ``fsync`` runs every ``fsync_ns`` of ticks (1 s by default), at each cycle end, after each stop
  event and at close: a power loss loses at most that much, provided the drive honours fsync.
* Any write error stops recording for good and raises RecordError: the caller stops the cell
  (an unrecorded run is not allowed). Nothing already written is touched; the file is append-only.

Full servo rate is kept around every event that is not routine (``pre_trigger_s`` before,
``post_trigger_s`` after, and around a failed cycle); the decimated stream (``decimated_hz``) and
the per-cycle summaries are continuous.
"""

from __future__ import annotations

import contextlib
import errno
import json
import math
import numbers
import os
import re
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np
from mcap.writer import CompressionType, Writer

from cellguard.control.events import ROUTINE_EVENTS, Event, EventKind
from cellguard.errors import RecordError
from cellguard.record import ros2
from cellguard.record.context import changed_keys, versions
from cellguard.record.index import PART_GLOB, TABLES, IndexWriter, clear_index, cycle_row, default_opener, event_row
from cellguard.record.json_values import plain
from cellguard.record.ring import TickRing
from cellguard.record.schemas import CHANNELS, CHUNK, TICKS
from cellguard.record.urdf import JointFrames

RECORD_FILE = "record.mcap"
# a record being started: renamed to RECORD_FILE once started (the old record stays whole until then)
STARTING_FILE = ".record.mcap.starting"
INDEX_DIR = "index"
PROFILE = "cellguard"
RECORD_VERSION = 2  # 1: log time = t_ns, cellguard channels only
DESCRIPTION_FILE = "robot_description.urdf"
# what a run writes in its --out folder besides the record and index: summary (runtime), baseline and fixes
# (diagnose), report (report), shadow (release); named here, below those layers
RUN_OUTPUTS = ("summary.json", "baseline.json", "fixes.json", "report.html", "shadow.json")
REPLAY_PAGES = "replay-cycle-*.html"  # ``cellguard replay``'s pages in a run folder: made from its record too
LIBRARY = "cellguard"  # the MCAP header's library: a record of this recorder's (``scan`` trusts its chunk layout)
_LOG_LEVEL = {0: ros2.FATAL, 1: ros2.ERROR, 2: ros2.WARN}  # stop category -> log level; else INFO (routine: DEBUG)
CHUNK_BYTES = 1 << 20  # [bytes] a long backlog is split into chunks of about this many bytes (messages)
# The pre-trigger ring is allocated before the first tick and holds, at the servo rate, the pre-trigger window, four
# chunks and one decimated period: at 1 kHz (the fastest servo rate a run drives) and these limits, at most 350 s of
# ticks, 55 MB for the arm's 6 joints (a pre_trigger_s of 1e5 s asked 13.4 GiB; inf overflowed)
MAX_WINDOW_S = 300.0  # [s] the longest full-rate window, before or after an event
MAX_CHUNK_NS = 10_000_000_000  # [ns] the longest chunk: what a crash may lose
MIN_DECIMATED_HZ = 0.1  # [Hz] the slowest continuous stream
MAX_DECIMATED_HZ = 1e6  # [Hz] faster than any servo (the reader takes a context's amounts below 1e9 only: a record
# written at 1e9 Hz read as damaged, its context lost)


def decimation_stride(dt_ns: int, decimated_hz: float) -> int:
    """Every how many servo ticks the decimated stream takes one: the rate nearest ``decimated_hz``, at least every
    tick (the readers work the stream's period out of the context with the same rule)."""
    return max(1, round(1e9 / dt_ns / decimated_hz))


def _whole(value) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _number(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)


@dataclass(frozen=True)
class RecordConfig:
    """How often data reaches the disk and at which rates ticks are kept."""

    chunk_ns: int = 100_000_000  # close an MCAP chunk at least every this much tick time [ns]
    fsync_ns: int = 1_000_000_000  # fsync at least every this much tick time [ns]
    decimated_hz: float = 50.0  # continuous tick stream [Hz]
    pre_trigger_s: float = 10.0  # full rate kept before an event [s]
    post_trigger_s: float = 5.0  # and after it [s]
    routine_events: frozenset[str] = ROUTINE_EVENTS
    index_part_rows: int = 5000  # Parquet rows per part file: about one file per day at a 20 s cycle
    context_every_s: float = 60.0  # repeat the unchanged context at a cycle start at least this often [s]

    def __post_init__(self):
        """RecordError naming the first field that is not a number in its range, before anything is created."""
        window = f"a finite number of seconds from 0 to MAX_WINDOW_S ({MAX_WINDOW_S:g} s)"
        checks = (  # in order: fsync_ns is compared with a chunk_ns checked already
            ("chunk_ns", lambda v: _whole(v) and 0 < v <= MAX_CHUNK_NS,
             f"an integer of ns from 1 to MAX_CHUNK_NS ({MAX_CHUNK_NS})"),
            ("fsync_ns", lambda v: _whole(v) and v >= self.chunk_ns, "an integer of ns, at least chunk_ns"),
            ("decimated_hz", lambda v: _number(v) and MIN_DECIMATED_HZ <= v <= MAX_DECIMATED_HZ,
             f"a rate from MIN_DECIMATED_HZ ({MIN_DECIMATED_HZ:g} Hz) to MAX_DECIMATED_HZ ({MAX_DECIMATED_HZ:g} Hz)"),
            ("pre_trigger_s", lambda v: _number(v) and 0 <= v <= MAX_WINDOW_S,
             f"{window}: the pre-trigger ring keeps that much at the servo rate in memory"),
            ("post_trigger_s", lambda v: _number(v) and 0 <= v <= MAX_WINDOW_S,
             f"{window}; to keep every tick, set decimated_hz to the servo rate"),
            ("index_part_rows", lambda v: _whole(v) and v >= 1, "an integer of at least 1"),
            ("context_every_s", lambda v: _number(v) and v > 0, "a finite number of seconds above 0"))
        for name, ok, rule in checks:
            if not ok(getattr(self, name)):
                raise RecordError(f"record config {name}: {getattr(self, name)!r} is not allowed: give {rule}")

    def to_dict(self) -> dict:
        return {"chunk_ns": self.chunk_ns, "fsync_ns": self.fsync_ns, "decimated_hz": self.decimated_hz,
                "pre_trigger_s": self.pre_trigger_s, "post_trigger_s": self.post_trigger_s,
                "routine_events": sorted(self.routine_events), "context_every_s": self.context_every_s}


class Recorder:
    """Writes one record (``record.mcap`` and ``index/``) into a folder. Not thread-safe: one thread calls it."""

    def __init__(self, stream: BinaryIO, *, joints: tuple[str, ...], dt_ns: int, context: dict,
                 config: RecordConfig = RecordConfig(), index: IndexWriter | None = None, name: str = RECORD_FILE,
                 epoch_wall_ns: int | None = None, description: tuple[str, JointFrames] | None = None,
                 record_id: str | None = None, start_ns: int = 0, slack: int | None = None):
        self.config, self.joints, self.dt_ns, self.name = config, tuple(joints), int(dt_ns), name
        self.start_ns = int(start_ns)  # the run clock when the record starts [ns]
        self.epoch_wall_ns = time.time_ns() - self.start_ns if epoch_wall_ns is None else int(epoch_wall_ns)
        self.record_id = record_id or uuid.uuid4().hex
        self._stream, self._index = stream, index
        self._failed: str | None = None
        self._stride = decimation_stride(dt_ns, config.decimated_hz)
        self._batch = max(1, config.chunk_ns // dt_ns)
        self._back = math.ceil(config.pre_trigger_s * 1e9 / dt_ns)
        # ``slack``: the ring is made in memory shared with a writer process forked next (``RunRecording``), once
        self._ring = TickRing(len(self.joints), self._back + 4 * self._batch + self._stride, slack)
        self._starting: Path | None = None  # where ``create`` started the record, until ``place`` renames it
        self._replace = False
        self._seq = {c.id: 0 for c in CHANNELS}
        self._pending: list[tuple[int, int, int, bytes, int]] = []  # (wall ns, order, channel, data, sequence)
        self._floor = 0  # log time of the last message written [ns since 1970]
        self._joint_states = ros2.JointStateEncoder(self.joints)
        self._urdf, self._frames = description if description is not None else (None, None)
        moving = self._frames.moving if self._frames is not None else []
        self._tf = ros2.TfEncoder([(j.parent, j.child) for _, j in moving]) if moving else None
        self._dec_next = 0  # next tick index the decimated stream has not considered
        self._full_done = 0  # ticks before this are on the full-rate channel or were skipped
        self._full_start = 0  # first tick of the current full-rate window
        self._full_until_ns = -1  # the full-rate window ends here
        self._last_flush_ns = self._next_flush_ns = self.start_ns
        self._next_fsync_ns = self.start_ns + config.fsync_ns
        self._context: dict | None = None
        self._context_t_ns = 0
        self._versions: dict[str, str] = {}
        self._where: dict[str, str | None] = {}
        self._cycle_start: dict[int, int] = {}
        self._begun: tuple[int, int] | None = None  # the cycle whose begin marker was written last, and that begin [ns]
        self._ended: tuple[int, int] | None = None  # that cycle and its end [ns] once its end marker is written
        self._guard(self._start, context)

    @classmethod
    def create(cls, folder: Path, *, joints, dt_ns: int, context: dict, config: RecordConfig = RecordConfig(),
               opener: Callable[[Path], BinaryIO] = default_opener, epoch_wall_ns: int | None = None,
               description: tuple[str, JointFrames] | None = None, replace: bool = False,
               start_ns: int = 0, slack: int | None = None, place: bool = True) -> Recorder:
        """Start a record in ``folder``; RecordError if it cannot be written or one is there already.

        The record starts as ``STARTING_FILE`` (header written, ring built) and only ``place`` renames it to
        ``RECORD_FILE``; ``place=False`` leaves that to the caller, once the rest of its start has worked (a
        ``RunRecording``'s writer process). A record already in ``folder`` is refused unless ``replace``; then it
        stays whole until ``place``: a start that failed after it was unlinked (no room for the header, no memory
        for the ring, no process forked) lost it and said "nothing was run". A start that fails leaves no file of
        its own behind; one killed leaves at most ``STARTING_FILE``, never read, removed by the next start.
        """
        folder = Path(folder)
        refuse_existing(folder, replace)
        starting = folder / STARTING_FILE
        try:
            folder.mkdir(parents=True, exist_ok=True)
            starting.unlink(missing_ok=True)  # a start killed before ``place``: its writer, if any, holds the lock
            stream = opener(starting)
        except OSError as exc:
            raise RecordError(f"{folder / RECORD_FILE}: cannot start the record ({_why(exc)}); "
                              f"nothing was run") from None
        epoch = time.time_ns() - start_ns if epoch_wall_ns is None else epoch_wall_ns
        record_id = uuid.uuid4().hex
        index = IndexWriter(folder / INDEX_DIR, epoch, config.index_part_rows, opener, record_id)
        try:
            recorder = cls(stream, joints=joints, dt_ns=dt_ns, context=context, config=config, index=index,
                           name=str(folder / RECORD_FILE), epoch_wall_ns=epoch, description=description,
                           record_id=record_id, start_ns=start_ns, slack=slack)
        except BaseException as exc:  # not even the start fitted: leave no record of its own behind
            _discard(stream, starting)
            if isinstance(exc, RecordError):
                raise RecordError(f"{folder / RECORD_FILE}: cannot start the record (no space or no access); "
                                  f"nothing was run") from None
            raise
        recorder._starting, recorder._replace = starting, replace
        if place:
            try:
                recorder.place()
            except BaseException:
                recorder.discard()
                raise
        return recorder

    def place(self) -> None:
        """Put the started record in place: ``STARTING_FILE`` renamed over ``RECORD_FILE`` (a reader or a hard link
        keeps the old bytes), then, with ``replace``, the old record's index parts and the files made from it
        (``RUN_OUTPUTS``, replay pages) removed (its baseline, bound to the old record, made the new run's diagnosis
        refuse it; a replay of its cycle N read as the new one's). RecordError if the rename fails: the old record
        and every file made from it are as they were (removed before the rename, they were lost while the record
        stayed, and a SIGKILL there left it without its index and summary); the new one is still to be discarded (by
        the writer process first, if any: see ``placed``). A SIGKILL between the rename and the removal leaves the
        old files beside the new record until the next ``--overwrite``: its index and baseline name the record they
        were made from (``query`` and ``diagnose`` refuse them), its summary and report are the old run's."""
        folder = self._starting.parent
        try:
            old = _made_from(folder) if self._replace else []
            os.replace(self._starting, self.name)
        except OSError as exc:
            raise RecordError(f"{self.name}: cannot start the record ({_why(exc)}); nothing was run") from None
        self._starting = None
        with contextlib.suppress(OSError):  # placed: a file left is one the new record's readers tell from its own
            clear_index(folder / INDEX_DIR)
        for path in old:
            with contextlib.suppress(OSError):
                path.unlink(missing_ok=True)

    @property
    def placed(self) -> bool:
        """Whether the record is at ``RECORD_FILE`` (``place``); read from the folder, so that a process forked before
        the record was placed (the writer) sees it too."""
        return self._starting is None or not os.path.lexists(self._starting)

    def discard(self) -> None:
        """Close and remove the record of a start that failed, if not placed: nothing of that start stays (an empty
        or header-only record.mcap blocked the folder, "already holds a record", and read as an empty run)."""
        if self._starting is not None:
            _discard(self._stream, self._starting)

    @property
    def ring(self) -> TickRing:
        """The pre-trigger ring: a ``RunRecording``'s loop adds the ticks to it (made shared, ``slack``)."""
        return self._ring

    # -- servo path ------------------------------------------------------------------------
    def tick(self, cycle: int, reference: np.ndarray, sent: np.ndarray, state) -> None:
        """One servo tick: what the executor asked, what was sent, what the robot measured."""
        self._ring.add(state.t_ns, cycle, reference, sent, state.q, state.qd, state.effort, state.current)
        if state.t_ns >= self._next_flush_ns:
            self._guard(self._flush, state.t_ns)

    def advance(self, n: int) -> None:
        """Take the ticks up to number ``n`` that another process put in the shared ring, as ``tick`` would."""
        ring, t_ns, capacity = self._ring, self._ring.t_ns, self._ring.capacity
        for i in range(ring.n, n):
            ring.n = i + 1
            if t_ns[i % capacity] >= self._next_flush_ns:
                self._guard(self._flush, int(t_ns[i % capacity]))

    def run_lost(self, why: str) -> None:
        """The run's process is gone before it finished the run: say so, since a file the writer finishes alone
        would otherwise read as a run that ended. At the last tick taken, in the cycle whose begin marker was written
        last; where that cycle had ended (killed between cycles), in none and 1 ns past its end, which the live
        process wrote: at the end, a reader that places an unstamped event by time (``diagnose``, closed spans) read
        the cycle as cut short. Never in a cycle the record does not mark (a tick stamped with a cycle whose begin was
        still queued when the process died), nor in one before any cycle begun."""
        t_ns, cycle = max(0, self._ring.last_t_ns()), None
        if self._ended is not None:
            t_ns = max(t_ns, self._ended[1] + 1)
        elif self._begun is not None:
            cycle, t_ns = self._begun[0], max(t_ns, self._begun[1])
        self.event(Event(t_ns, EventKind.RUN_PROCESS_LOST, why), cycle)

    # -- lower-rate streams ----------------------------------------------------------------
    def chunk(self, chunk, t_received_ns: int, latency_ns: int) -> None:
        """An action chunk as the policy returned it, when it reached the executor."""
        actions = np.asarray(chunk.actions, dtype=np.float64)
        dof = actions.shape[1] if actions.ndim == 2 else 0
        uncertainty = np.zeros(0) if chunk.uncertainty is None else chunk.uncertainty
        data = CHUNK.encode({"t_obs_ns": chunk.t_obs_ns, "t_received_ns": t_received_ns, "latency_ns": latency_ns,
                             "dt_ns": chunk.dt_ns, "dof": dof, "actions": actions, "uncertainty": uncertainty})
        self._guard(self._add, 4, t_received_ns, data)

    def measurements(self, t_ns: int, cycle: int, values: dict) -> None:
        """Camera and fixture readings as the policy saw them."""
        self._guard(self._json, 7, t_ns, {"t_ns": t_ns, "cycle": cycle, "measurements": values})

    def event(self, event: Event, cycle: int | None = None) -> None:
        """An event (JSON and log line); anything not routine opens a full-rate window around it. ``cycle``: the
        cycle begun last (``RunRecording``); none once that cycle's end is written, whatever the event's time: spans
        are closed (the cycle's last tick, and a stop read on it, lie at its end), and the retreat's first event, after
        the end, lies at that time too."""
        cycle = None if self._ended is not None and cycle == self._ended[0] else cycle
        fields = _event_fields(event)
        routine = event.kind in self.config.routine_events
        self._guard(self._json, 5, event.t_ns, {k: v for k, v in {"cycle": cycle, **fields}.items() if v is not None})
        level = _log_level(event, routine)
        self._guard(self._add, 13, event.t_ns, ros2.log_message(self.epoch_wall_ns + event.t_ns, level,
                                                                "cellguard", _log_text(fields, cycle)))
        if self._index is not None:
            self._guard(self._index.add, "events", event_row(fields, cycle, {**self._versions, **self._where}))
        if not routine:
            self._trigger(event.t_ns)
        if event.category is not None:  # a stop: on disk now
            self._guard(self._flush, max(event.t_ns, self._ring.last_t_ns()))
            self._guard(self._sync)

    def set_context(self, context: dict, t_ns: int) -> None:
        """Record the context if it changed (a new policy, a recalibration, a moved datum), or repeat it when due."""
        if context != self._context:
            self._guard(self._write_context, context, t_ns)
        elif t_ns - self._context_t_ns >= self.config.context_every_s * 1e9:
            self._guard(self._write_context, context, t_ns, True)

    def cycle_begin(self, cycle: int, phase: str, t_ns: int) -> None:
        self._cycle_start[cycle] = t_ns
        self._begun, self._ended = (cycle, t_ns), None  # a cycle number begun again is open again
        self._guard(self._json, 6, t_ns, {"marker": "begin", "cycle": cycle, "phase": phase, "t_start_ns": t_ns,
                                          **self._versions})

    def cycle_end(self, outcome: dict, t_ns: int) -> None:
        """The cycle's outcome and its features (computed at cycle end); also one index row."""
        cycle = int(outcome["cycle"])
        self._ended = (cycle, t_ns)
        features = {k: _finite(v) for k, v in outcome.get("features", {}).items()}
        base = {"cycle": cycle, "phase": outcome["phase"], "t_start_ns": self._cycle_start.pop(cycle, t_ns),
                "t_end_ns": t_ns, "success": bool(outcome["success"])}
        row = cycle_row(**base, versions={**self._versions, **self._where}, features=features)
        rest = {k: v for k, v in outcome.items() if k not in ("features", *base)}
        self._guard(self._json, 6, t_ns, {"marker": "end", **base, **self._versions, "outcome": rest,
                                          "features": features})
        if self._index is not None:
            self._guard(self._index.add, "cycles", row)
        if not row["success"]:
            self._trigger(t_ns)
        self._guard(self._flush, max(t_ns, self._ring.last_t_ns()))
        self._guard(self._sync)

    def close(self) -> None:
        """Write the pending ticks, the context again, the summary and the index; fsync; close the file."""
        try:
            if self._failed is None:
                self._guard(self._flush, self._ring.last_t_ns())
                self._guard(self._finish)
        finally:
            try:
                self._stream.close()  # after a failure, this may fail too (buffered bytes on a full disk)
            except OSError as exc:
                self._failed = self._failed or _why(exc)

    @property
    def failed(self) -> str | None:
        """Why recording stopped, or None while it works."""
        return self._failed

    # -- internals -------------------------------------------------------------------------
    def _guard(self, fn, *args):
        if self._failed is not None:
            raise RecordError(f"{self.name}: recording stopped earlier ({self._failed})")
        try:
            return fn(*args)
        except OSError as exc:
            self._failed = _why(exc)
            raise RecordError(f"{self.name}: cannot write the record ({self._failed}); "
                              f"what was written before is intact") from None

    def _start(self, context: dict) -> None:
        self._writer = Writer(self._stream, chunk_size=1 << 30, compression=CompressionType.ZSTD, enable_crcs=True)
        self._writer.start(profile=PROFILE, library=LIBRARY)
        self._writer.add_metadata("foxglove", _foxglove_metadata(context, self.record_id))
        self._writer.add_metadata("cellguard", self._facts(context))
        start, began = self.start_ns, self.epoch_wall_ns + self.start_ns
        if self._urdf is not None:
            self._writer.add_attachment(began, began, DESCRIPTION_FILE, "application/xml", self._urdf.encode())
        for c in CHANNELS:
            schema = self._writer.register_schema(c.schema_name, c.schema_encoding, c.schema_text.encode())
            meta = {"joints": ",".join(self.joints)} if c.message_encoding == "cdr" and "ticks" in c.topic else {}
            self._writer.register_channel(c.topic, c.message_encoding, schema, meta)
        self._write_context(context, start)
        if self._urdf is not None:
            self._add(12, start, ros2.string_message(self._urdf))
            fixed = self._frames.fixed
            poses = np.array([[[*xyz, *quat] for _, _, xyz, quat in fixed]])
            self._add(11, start, ros2.TfEncoder([(p, c) for p, c, _, _ in fixed]).encode([began], poses)[0])
        self._write_pending()
        self._stream.flush()
        _fsync(self._stream)

    def _facts(self, context: dict) -> dict[str, str]:
        """The ``cellguard`` metadata record: what identifies the run, as strings (MCAP metadata is str -> str)."""
        policy, emb = context.get("policy") or {}, context.get("embodiment") or {}
        stamps = versions(context)
        facts = {"record_version": RECORD_VERSION, "record_id": self.record_id, "epoch_wall_ns": self.epoch_wall_ns,
                 "start_ns": self.start_ns,
                 "start_utc": _utc(self.epoch_wall_ns + self.start_ns), "site": context.get("site"), "cell_id": context.get("cell_id"),
                 "cell": context.get("cell"), "robot": emb.get("robot"), "profile_version": emb.get("version"),
                 "profile_sha256": emb.get("sha256"), "calibration_dates": ",".join(emb.get("calibration_dates", [])),
                 "policy_source": policy.get("source"), "policy_sha256": policy.get("sha256"),
                 "servo_period_ns": context.get("servo_period_ns"), "joints": ",".join(self.joints), **stamps}
        return {k: "" if v is None else str(v) for k, v in facts.items()}

    def _write_context(self, context: dict, t_ns: int, repeat: bool = False) -> None:
        changed = [] if repeat else changed_keys(self._context, context)
        self._context, self._versions, self._context_t_ns = context, versions(context), t_ns
        self._where = {"site": context.get("site"), "cell_id": context.get("cell_id")}
        self._json(1, t_ns, {"t_ns": t_ns, "epoch_wall_ns": self.epoch_wall_ns, "start_ns": self.start_ns,
                             "record_id": self.record_id,
                             "record_version": RECORD_VERSION, "repeat": repeat,
                             "version": self._versions["context_version"], "changed": changed,
                             "versions": self._versions, "context": context})

    def _add(self, channel: int, t_ns: int, data: bytes) -> None:
        """Queue a message of the open chunk; it is written, in time order, when the chunk closes."""
        self._seq[channel] += 1
        self._pending.append((self.epoch_wall_ns + int(t_ns), len(self._pending), channel, data, self._seq[channel]))

    def _json(self, channel: int, t_ns: int, payload: dict) -> None:
        self._add(channel, t_ns, json.dumps(plain(payload), allow_nan=False).encode())

    def _write_pending(self) -> None:
        """Write the queued messages sorted by time (none before one already written) and close the chunk."""
        self._pending.sort()
        size = 0
        for wall, _, channel, data, seq in self._pending:
            self._floor = max(self._floor, wall)
            self._writer.add_message(channel, self._floor, data, wall, seq)
            size += len(data)
            if size >= CHUNK_BYTES:  # a long backlog goes out in chunks of about the usual size
                self._writer.flush()
                size = 0
        self._pending = []
        self._writer.flush()

    def _ticks(self, channel: int, start: int, stop: int, step: int) -> None:
        span = self._batch * step
        decimated = channel == 2
        for first in range(start, stop, span):
            batch = self._ring.batch(first, min(stop, first + span), step)
            batch["joints"] = self.joints
            self._add(channel, int(batch["t_ns"][0]), TICKS.encode(batch))
            wall, times = self.epoch_wall_ns + batch["t_ns"], batch["t_ns"].tolist()
            for t, data in zip(times, self._joint_states.encode(wall, batch["q_meas"], batch["qd_meas"],
                                                                batch["effort"])):
                self._add(8 if decimated else 9, t, data)
            if decimated and self._tf is not None:  # same time as its joint state, queued after it
                for t, data in zip(times, self._tf.encode(wall, self._frames.poses(batch["q_meas"]))):
                    self._add(10, t, data)

    def _trigger(self, t_ns: int) -> None:
        if self._back == 0 and self.config.post_trigger_s == 0:
            return  # full-rate windows switched off
        if self._full_until_ns < self._last_flush_ns:  # no window open: start one, reaching back
            self._full_start = self._ring.n - 1 - self._back
        self._full_until_ns = max(self._full_until_ns, t_ns + round(self.config.post_trigger_s * 1e9))

    def _flush(self, t_ns: int) -> None:
        ring, n = self._ring, self._ring.n
        first = -(-max(self._dec_next, ring.oldest) // self._stride) * self._stride
        if first < n:
            self._ticks(2, first, n, self._stride)
        self._dec_next = n
        if self._full_until_ns >= self._last_flush_ns:
            start = max(self._full_done, ring.oldest, self._full_start)
            if start < n:
                self._ticks(3, start, n, 1)
            self._full_done = n
        self._write_pending()
        self._last_flush_ns = t_ns
        self._next_flush_ns = t_ns + self.config.chunk_ns
        if t_ns >= self._next_fsync_ns:
            self._sync()

    def _sync(self) -> None:
        self._stream.flush()
        _fsync(self._stream)
        self._next_fsync_ns = self._ring.last_t_ns() + self.config.fsync_ns

    def _finish(self) -> None:
        if self._context is not None:  # the context once more, outside any chunk, indexed in the summary
            self._writer.add_metadata("cellguard.context", {  # with what a reader must know when the start is lost
                "record_id": self.record_id, "t_ns": str(self._context_t_ns), "record_version": str(RECORD_VERSION),
                "epoch_wall_ns": str(self.epoch_wall_ns), "start_ns": str(self.start_ns),
                "context": json.dumps(plain(self._context), allow_nan=False)})
        self._writer.finish()
        self._sync()  # the record is whole on disk before the index, derived from it, is written
        if self._index is not None:
            try:
                self._index.flush()
            except OSError as exc:
                self._failed = _why(exc)
                raise RecordError(f"{self._index.folder}: cannot write the index ({self._failed}); {self.name} is "
                                  f"finished and whole") from None


def refuse_existing(folder: Path, replace: bool = False) -> None:
    """RecordError if ``folder`` lies inside a run folder (its record's folder, whose files are the record's), or
    holds a record or anything a run writes (a summary whose record was moved away is still someone's) and
    replacing it was not asked for; before anything runs."""
    folder = Path(folder)
    try:
        run = next((d for d in folder.resolve().parents if (d / RECORD_FILE).exists()), None)  # after links
        there = [name for name in (RECORD_FILE, *RUN_OUTPUTS) if os.path.lexists(folder / name)]
        if not there and _index_parts(folder / INDEX_DIR):
            there = [f"{INDEX_DIR}/ (index parts)"]
    except (OSError, RuntimeError) as exc:  # a name too long, no access, a link loop
        raise RecordError(f"--out {folder}: cannot be checked ({getattr(exc, 'strerror', None) or exc})") from None
    if run is not None:
        raise RecordError(f"--out {folder}: is in the run folder {run}, which holds a record; a run never writes "
                          f"into another's run folder: choose an --out outside it")
    if there and not replace:
        what = f"a record ({RECORD_FILE})" if there[0] == RECORD_FILE else f"{there[0]}, which a run writes"
        raise RecordError(f"--out {folder}: already holds {what}; a run never overwrites one: "
                          f"choose another --out folder (or pass --overwrite to replace it)")


def _made_from(folder: Path) -> list[Path]:
    """The files made from the old record in ``folder`` that ``place`` removes (its index parts: ``clear_index``).
    IsADirectoryError for a folder at a run output's name, before anything is renamed (it is not one, and stays)."""
    outputs = [folder / name for name in RUN_OUTPUTS if os.path.lexists(folder / name)]
    for path in outputs:
        if path.is_dir() and not path.is_symlink():
            raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), str(path))
    pages = [p for p in folder.glob(REPLAY_PAGES)  # as replay names them
             if re.fullmatch(r"replay-cycle-\d+\.html", p.name) and not p.is_dir()]
    return [*outputs, *pages]


def _index_parts(folder: Path) -> bool:
    """Whether ``folder`` holds index parts (those a run with ``replace`` removes)."""
    return folder.is_dir() and any(next((folder / t).glob(PART_GLOB), None) for t in TABLES)


def _foxglove_metadata(context: dict, record_id: str) -> dict[str, str]:
    """What Foxglove's data platform and Edge Sites read: the device by name, and an idempotency key."""
    device = "/".join(str(x) for x in (context.get("site"), context.get("cell_id")) if x) or str(context.get("cell"))
    return {"deviceName": device, "key": record_id}


def _utc(wall_ns: int) -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(wall_ns // 1_000_000_000)) + f".{wall_ns % 10**9:09d}Z"


def _log_text(fields: dict, cycle: int | None) -> str:
    where = f" joint {fields['joint']}" if fields.get("joint") else ""
    stop = f" (stop category {fields['category']})" if fields.get("category") is not None else ""
    when = "between cycles" if cycle is None else f"cycle {cycle}"  # before the first, after a cycle's end
    return f"[{fields['kind']}] {when}{where}{stop}: {fields['reason']}"


def _log_level(event: Event, routine: bool) -> int:
    """The event's ROS log level: by its stop category; a recovery that ended other than ``resumed`` (failed,
    escalated, gave_up, cut_off; an attempt that could not be planned, or no recovery left: no attempt's fields)
    WARN, routine as its kind is: a technician must see it among the warnings in Foxglove's Log panel, not in the
    DEBUG lines filtered away; else INFO, DEBUG if routine."""
    if event.category in _LOG_LEVEL:
        return _LOG_LEVEL[event.category]
    if event.kind == EventKind.RECOVERY_END and (event.recovery or {}).get("outcome") != "resumed":
        return ros2.WARN
    return ros2.DEBUG if routine else ros2.INFO


def _event_fields(event: Event) -> dict:
    return {"t_ns": event.t_ns, "kind": event.kind, "reason": event.reason, "joint": event.joint,
            "asked": _finite(event.asked), "sent": _finite(event.sent), "category": event.category,
            "recovery": event.recovery}


def _finite(value):
    """JSON has no NaN: a non-finite number is recorded as null."""
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def _discard(stream, path: Path) -> None:
    """Close ``stream`` and remove ``path``, its file, whatever fails."""
    with contextlib.suppress(OSError):
        stream.close()
    with contextlib.suppress(OSError):
        path.unlink()


def _fsync(stream) -> None:
    try:
        fd = stream.fileno()
    except (AttributeError, OSError, ValueError):
        return  # an in-memory stream has nothing to sync
    os.fsync(fd)


def _why(exc: OSError) -> str:
    name = errno.errorcode.get(exc.errno, "") if exc.errno else ""
    return f"{name}: {exc.strerror or exc}" if name else str(exc)
