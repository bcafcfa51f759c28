"""The recorder: every tick, chunk, event and cycle of a run, written so that a crash loses little.

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

import errno
import json
import math
import os
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np
from mcap.writer import CompressionType, Writer

from cellguard.control.events import ROUTINE_EVENTS, Event
from cellguard.errors import RecordError
from cellguard.record.context import changed_keys, versions
from cellguard.record.index import IndexWriter, cycle_row, default_opener, event_row
from cellguard.record.ring import TickRing
from cellguard.record.schemas import CHANNELS, CHUNK, TICKS

RECORD_FILE = "record.mcap"
INDEX_DIR = "index"
PROFILE = "cellguard"


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

    def __post_init__(self):
        checks = {"chunk_ns": self.chunk_ns > 0, "fsync_ns": self.fsync_ns >= self.chunk_ns,
                  "decimated_hz": self.decimated_hz > 0, "pre_trigger_s": self.pre_trigger_s >= 0,
                  "post_trigger_s": self.post_trigger_s >= 0, "index_part_rows": self.index_part_rows >= 1}
        for name, ok in checks.items():
            if not ok:
                raise RecordError(f"record config {name}: {getattr(self, name)!r} is not allowed "
                                  f"(chunk_ns > 0, fsync_ns >= chunk_ns, rates and windows >= 0)")

    def to_dict(self) -> dict:
        return {"chunk_ns": self.chunk_ns, "fsync_ns": self.fsync_ns, "decimated_hz": self.decimated_hz,
                "pre_trigger_s": self.pre_trigger_s, "post_trigger_s": self.post_trigger_s,
                "routine_events": sorted(self.routine_events)}


class Recorder:
    """Writes one record (``record.mcap`` and ``index/``) into a folder. Not thread-safe."""

    def __init__(self, stream: BinaryIO, *, joints: tuple[str, ...], dt_ns: int, context: dict,
                 config: RecordConfig = RecordConfig(), index: IndexWriter | None = None, name: str = RECORD_FILE,
                 epoch_wall_ns: int | None = None):
        self.config, self.joints, self.dt_ns, self.name = config, tuple(joints), int(dt_ns), name
        self.epoch_wall_ns = time.time_ns() if epoch_wall_ns is None else int(epoch_wall_ns)
        self._stream, self._index = stream, index
        self._failed: str | None = None
        self._stride = max(1, round(1e9 / dt_ns / config.decimated_hz))
        self._batch = max(1, config.chunk_ns // dt_ns)
        self._back = math.ceil(config.pre_trigger_s * 1e9 / dt_ns)
        self._ring = TickRing(len(self.joints), self._back + 4 * self._batch + self._stride)
        self._seq = {c.id: 0 for c in CHANNELS}
        self._dec_next = 0  # next tick index the decimated stream has not considered
        self._full_done = 0  # ticks before this are on the full-rate channel or were skipped
        self._full_start = 0  # first tick of the current full-rate window
        self._full_until_ns = -1  # the full-rate window ends here
        self._last_flush_ns = 0
        self._next_flush_ns = 0
        self._next_fsync_ns = config.fsync_ns
        self._context: dict | None = None
        self._versions: dict[str, str] = {}
        self._cycle_start: dict[int, int] = {}
        self._guard(self._start, context)

    @classmethod
    def create(cls, folder: Path, *, joints, dt_ns: int, context: dict, config: RecordConfig = RecordConfig(),
               opener: Callable[[Path], BinaryIO] = default_opener, epoch_wall_ns: int | None = None) -> Recorder:
        """Start a record in ``folder`` (replacing an earlier one there); RecordError if it cannot be written."""
        folder = Path(folder)
        try:
            folder.mkdir(parents=True, exist_ok=True)
            shutil.rmtree(folder / INDEX_DIR, ignore_errors=True)
            stream = opener(folder / RECORD_FILE)
        except OSError as exc:
            raise RecordError(f"{folder / RECORD_FILE}: cannot start the record ({_why(exc)}); "
                              f"nothing was run") from None
        epoch = time.time_ns() if epoch_wall_ns is None else epoch_wall_ns
        index = IndexWriter(folder / INDEX_DIR, epoch, config.index_part_rows, opener)
        return cls(stream, joints=joints, dt_ns=dt_ns, context=context, config=config, index=index,
                   name=str(folder / RECORD_FILE), epoch_wall_ns=epoch)

    # -- servo path ------------------------------------------------------------------------
    def tick(self, cycle: int, reference: np.ndarray, sent: np.ndarray, state) -> None:
        """One servo tick: what the executor asked, what was sent, what the robot measured."""
        self._ring.add(state.t_ns, cycle, reference, sent, state.q, state.qd, state.effort, state.current)
        if state.t_ns >= self._next_flush_ns:
            self._guard(self._flush, state.t_ns)

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
        """An event; anything not routine opens a full-rate window around it."""
        fields = _event_fields(event)
        self._guard(self._json, 5, event.t_ns, {"cycle": cycle, **fields})
        if self._index is not None:
            self._guard(self._index.add, "events", event_row(fields, cycle, self._versions))
        if event.kind not in self.config.routine_events:
            self._trigger(event.t_ns)
        if event.category is not None:
            self._guard(self._sync)

    def set_context(self, context: dict, t_ns: int) -> None:
        """Record the context if it changed (a new policy, a recalibration, a moved datum)."""
        if context != self._context:
            self._guard(self._write_context, context, t_ns)

    def cycle_begin(self, cycle: int, phase: str, t_ns: int) -> None:
        self._cycle_start[cycle] = t_ns
        self._guard(self._json, 6, t_ns, {"marker": "begin", "cycle": cycle, "phase": phase, "t_start_ns": t_ns,
                                          **self._versions})

    def cycle_end(self, outcome: dict, t_ns: int) -> None:
        """The cycle's outcome and its features (computed at cycle end); also one index row."""
        cycle = int(outcome["cycle"])
        features = {k: _finite(v) for k, v in outcome.get("features", {}).items()}
        base = {"cycle": cycle, "phase": outcome["phase"], "t_start_ns": self._cycle_start.pop(cycle, t_ns),
                "t_end_ns": t_ns, "success": bool(outcome["success"])}
        row = cycle_row(**base, versions=self._versions, features=features)
        rest = {k: v for k, v in outcome.items() if k not in ("features", *base)}
        self._guard(self._json, 6, t_ns, {"marker": "end", **base, **self._versions, "outcome": rest,
                                          "features": features})
        if self._index is not None:
            self._guard(self._index.add, "cycles", row)
        if not row["success"]:
            self._trigger(t_ns)
        self._guard(self._sync)

    def close(self) -> None:
        """Write the pending ticks, the summary and the index; fsync; close the file."""
        if self._failed is not None:
            self._stream.close()
            return
        try:
            self._guard(self._flush, self._ring.last_t_ns())
            self._guard(self._finish)
        finally:
            self._stream.close()

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
        self._writer.start(profile=PROFILE, library="cellguard")
        for c in CHANNELS:
            schema = self._writer.register_schema(c.schema_name, c.schema_encoding, c.schema_text.encode())
            meta = {"joints": ",".join(self.joints)} if c.message_encoding == "cdr" and "ticks" in c.topic else {}
            self._writer.register_channel(c.topic, c.message_encoding, schema, meta)
        self._write_context(context, 0)
        self._writer.flush()
        self._stream.flush()
        _fsync(self._stream)

    def _write_context(self, context: dict, t_ns: int) -> None:
        changed = changed_keys(self._context, context)
        self._context, self._versions = context, versions(context)
        self._json(1, t_ns, {"t_ns": t_ns, "epoch_wall_ns": self.epoch_wall_ns,
                             "version": self._versions["context_version"], "changed": changed,
                             "versions": self._versions, "context": context})

    def _add(self, channel: int, log_time: int, data: bytes) -> None:
        self._seq[channel] += 1
        self._writer.add_message(channel, log_time, data, max(log_time, self._ring.last_t_ns()), self._seq[channel])

    def _json(self, channel: int, t_ns: int, payload: dict) -> None:
        self._add(channel, t_ns, json.dumps(_plain(payload), allow_nan=False).encode())

    def _ticks(self, channel: int, start: int, stop: int, step: int) -> None:
        span = self._batch * step
        for first in range(start, stop, span):
            batch = self._ring.batch(first, min(stop, first + span), step)
            batch["joints"] = self.joints
            self._add(channel, int(batch["t_ns"][0]), TICKS.encode(batch))
            if first + span < stop:  # a long pre-trigger backlog goes out in chunks of the usual size
                self._writer.flush()

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
        self._writer.flush()
        self._last_flush_ns = t_ns
        self._next_flush_ns = t_ns + self.config.chunk_ns
        if t_ns >= self._next_fsync_ns:
            self._sync()

    def _sync(self) -> None:
        self._stream.flush()
        _fsync(self._stream)
        self._next_fsync_ns = self._ring.last_t_ns() + self.config.fsync_ns

    def _finish(self) -> None:
        self._writer.finish()
        if self._index is not None:
            self._index.flush()
        self._sync()


def _event_fields(event: Event) -> dict:
    return {"t_ns": event.t_ns, "kind": event.kind, "reason": event.reason, "joint": event.joint,
            "asked": _finite(event.asked), "sent": _finite(event.sent), "category": event.category}


def _finite(value):
    """JSON has no NaN: a non-finite number is recorded as null."""
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def _plain(value):
    """Plain JSON values: numpy to lists and numbers, non-finite floats to null."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _fsync(stream) -> None:
    try:
        fd = stream.fileno()
    except (AttributeError, OSError, ValueError):
        return  # an in-memory stream has nothing to sync
    os.fsync(fd)


def _why(exc: OSError) -> str:
    name = errno.errorcode.get(exc.errno, "") if exc.errno else ""
    return f"{name}: {exc.strerror or exc}" if name else str(exc)
