"""Reading a cellguard record: the API that diagnosis, reports and the CLI build on.

Contract (fields may be added, not renamed)::

    from cellguard.record.reader import open_record

    rec = open_record("out/")        # a run folder holding record.mcap, or the .mcap file itself
    rec.context                      # dict: context at the start (policy source and sha256, its action_map
                                     #   if mapped; embodiment profile sha256, calibration dates and
                                     #   document; envelope, fixture_datum,
                                     #   camera_calibration, site, cell_id, scenario, software versions)
    rec.contexts                     # [ContextChange(t_ns, version, changed, versions, context)], one per change
    rec.epoch_wall_ns                # wall clock at t_ns == 0 [ns since 1970] (display only; order by t_ns)
    rec.start_ns, rec.start_wall_ns  # the run clock when the record started (wall time: since boot), and
                                     #   the wall clock then [ns since 1970]
    rec.record_id, rec.version       # 32 hex digits (None before version 2); record format version (1 or 2)
    rec.context_loss                 # None, or a sentence: the first context was lost and where it came from
    for c in rec.cycles():           # CycleRecord, in time order, one per completed cycle:
        c.cycle, c.phase             #   int, "acceptance" | "production"
        c.t_start_ns, c.t_end_ns     #   int ns, the record's clock
        c.success, c.features        #   bool, {name: float} computed at cycle end (NaN where not finite)
        c.outcome, c.versions        #   the cell's outcome (SI), {policy_version, calibration_version, ...}
    for e in rec.events():           # EventRecord, in time order: t_ns, kind, category (0/1/2 or None),
        ...                          #   joint, asked, sent, reason, cycle (None: between cycles, as a tick's)
    rec.ticks(cycle=12)              # Ticks: t_ns (n,), cycle (n,), joints, q_ref, q_cmd, q_meas, qd_meas,
                                     #   effort, current (n, dof) float64; rate="decimated" | "full" | "all";
                                     #   cycle is NO_CYCLE (-1) for a tick between cycles (a retreat, a settling)
    rec.tick_parts("all", rows)      # the same ticks of the whole record, about `rows` values a field at a time
    rec.cycle_spans()                # {cycle: (t_start_ns, t_end_ns or None: its end not recorded)}: the index's
                                     #   row, else the markers; of a cycle marked twice the last
    rec.chunks()                     # RecordedChunk: the policy's chunks as received
    rec.measurements()               # Measurement: t_ns, cycle, names, values (n,) of the readings the policy saw
    rec.health()                     # Health: finished, truncated, chunks ok/damaged, sequence gaps, writing
    rec.writing                      # None, or who still writes the record ("a running process (pid N)")

A truncated or damaged file opens: every chunk that passes its CRC is read, a damaged one is
skipped, so is a message that does not decode or fit its schema (a context whose fields readers
use have other types included), and ``health()`` says what was lost. The record's format, epoch
and start are taken from its first readable context (written with the log times, in a chunk with a
CRC): the metadata record at the file's start has no CRC, and one that says otherwise is reported
as damage. Messages are read a chunk or two at a time, so a long record takes no more memory.
``open_record`` raises RecordError only when nothing can be read; ``strict=True`` also raises when
anything was lost. A record whose run still holds its folder (``folder_lock``) when it is opened is read as far
as it is written: its unfinished end is no damage, and ``health()`` says who is writing it.
"""

from __future__ import annotations

import bisect
import collections
import datetime as dt
import hashlib
import itertools
import math
import os
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from mcap.records import Message

from cellguard.errors import RecordError
from cellguard.record import folder_lock
from cellguard.record.index import indexed_run
from cellguard.record.json_values import loads
from cellguard.record.scan import ChunkRef, Layout, open_buffer, read_chunk, scan
from cellguard.record.schemas import CHUNK, TICK_FIELDS, TICKS, file_ids, not_cellguard
from cellguard.record.writer import INDEX_DIR, RECORD_FILE, RECORD_VERSION

RATES = ("decimated", "full", "all")
NO_CYCLE = -1  # the cycle of a tick that lies in none: between a cycle's end and the next one's start
_TICK_TOPICS = {"decimated": "/ticks/decimated", "full": "/ticks/full"}


@dataclass(frozen=True)
class ContextChange:
    t_ns: int
    version: str
    changed: tuple[str, ...]
    versions: dict
    context: dict


@dataclass(frozen=True)
class CycleRecord:
    cycle: int
    phase: str
    t_start_ns: int
    t_end_ns: int
    success: bool
    features: dict[str, float]
    outcome: dict
    versions: dict[str, str]


@dataclass(frozen=True)
class EventRecord:
    t_ns: int
    kind: str
    reason: str
    category: int | None = None
    joint: str | None = None
    asked: float | None = None
    sent: float | None = None
    cycle: int | None = None
    recovery: dict | None = field(default=None, hash=False)  # a recovery_end's attempt as fields (older: None)


@dataclass(frozen=True)
class RecordedChunk:
    t_obs_ns: int
    t_received_ns: int
    latency_ns: int
    dt_ns: int
    actions: np.ndarray  # (H, dof), SI
    uncertainty: np.ndarray | None


@dataclass(frozen=True)
class Measurement:
    """The camera and fixture readings shown to the policy at ``t_ns``, flattened: ``names`` as ``key.i``."""

    t_ns: int
    cycle: int | None
    names: tuple[str, ...]
    values: np.ndarray  # (len(names),) SI


@dataclass(frozen=True)
class Ticks:
    """Ticks in time order; arrays (n,) and (n, dof), SI, float64. ``cycle``: the cycle each tick lies in, by its
    span (``cycle_spans``), else ``NO_CYCLE`` (the recorder stamps a tick with the cycle begun last, so the retreat or a
    stop's settling after a cycle's end carried that cycle's number)."""

    joints: tuple[str, ...]
    t_ns: np.ndarray
    cycle: np.ndarray
    q_ref: np.ndarray
    q_cmd: np.ndarray
    q_meas: np.ndarray
    qd_meas: np.ndarray
    effort: np.ndarray
    current: np.ndarray

    def __len__(self) -> int:
        return len(self.t_ns)


# what decoding a malformed message raises: it is skipped and noted, never a traceback
MALFORMED = (RecordError, ValueError, KeyError, TypeError, AttributeError, IndexError, OverflowError)


class UnorderedTicks(RecordError):
    """A tick batch reaches back before ticks ``tick_parts`` handed on already: not as the recorder writes (a crafted
    file); ``ticks()`` reads such a record whole."""


@dataclass(frozen=True)
class Health:
    """What a full read found. ``ok`` only for a finished file with nothing skipped."""

    finished: bool
    truncated: bool
    chunks_ok: int
    chunks_damaged: int
    damage: tuple[str, ...]
    gaps: dict[str, tuple[tuple[int, int], ...]]  # topic -> missing sequence ranges (first, last)
    messages: dict[str, int]
    span_ns: tuple[int, int] | None  # first and last message time read, on the record's clock
    context_loss: str | None = None  # the first context could not be read (and where it came from instead)
    off_schema: dict[str, int] = field(default_factory=dict)  # topic -> messages skipped as malformed
    recovered: str | None = None  # a copy made by ``record recover``: what a full read of its source found
    facts: str | None = None  # the metadata record states another format, epoch or start than the context
    repeats: dict[str, int] = field(default_factory=dict)  # topic -> messages whose sequence number is not new
    writing: str | None = None  # the unfinished file's run still holds its folder: who ("a running process (pid N)")
    unindexed: dict[str, int] = field(default_factory=dict)  # topic -> messages their chunks' message indexes leave out

    @property
    def ok(self) -> bool:
        return self.finished and not self.truncated and self.intact

    @property
    def intact(self) -> bool:
        """Nothing read was lost: what ``ok`` asks but for a finished file (a record still being written has
        no end yet, and the record it holds so far may be whole)."""
        return not self.damage and not any(self.gaps.values()) and self.context_loss is None and self.facts is None

    @property
    def recoverable(self) -> bool:
        """A finished copy (``record recover``) would read more: the file is unfinished or has damaged bytes.
        A malformed message or a repeated sequence number is copied as it is, so it alone is not; metadata that
        disagrees with the context is written as the context states it."""
        return (not self.finished or self.truncated or len(self.damage) > len(self.off_schema) + len(self.repeats)
                or self.facts is not None)

    def describe(self) -> str:
        copy = f"; a recovered copy of a record that was {self.recovered}" if self.recovered else ""
        if self.ok:
            return f"complete: {self.chunks_ok} chunks, {sum(self.messages.values())} messages{copy}"
        state = (f"still being written by {self.writing}" if self.writing
                 else "truncated" if self.truncated else "not finished" if not self.finished
                 else "damaged" if self.damage or self.context_loss or self.facts else "finished, with gaps")
        notes = "".join(f"; {note}" for note in (self.context_loss, self.facts) if note)
        notes += "".join(f"; {n} {topic} message(s) malformed, skipped" for topic, n in self.off_schema.items())
        notes += "".join(f"; {n} {topic} message(s) repeat a sequence number" for topic, n in self.repeats.items())
        notes += "".join(f"; {n} {topic} message(s) missing from their chunks' message indexes (read from the chunks)"
                         for topic, n in self.unindexed.items())
        lost = sum(b - a + 1 for g in self.gaps.values() for a, b in g)
        span = ("" if self.span_ns is None
                else f", readable {self.span_ns[0] * 1e-9:.3f} s to {self.span_ns[1] * 1e-9:.3f} s")
        read = "read so far" if self.writing else "recovered"
        return (f"{state}: {read} {self.chunks_ok} chunks ({sum(self.messages.values())} messages{span}); "
                f"{self.chunks_damaged} damaged chunks skipped, {lost} messages missing by sequence number"
                f"{notes}{copy}")


def open_record(path: Path | str, strict: bool = False) -> Record:
    """Open a record folder (or .mcap file). RecordError if nothing is readable (or, strict, if anything is lost)."""
    file = record_file(path)
    try:
        there = file.exists()
    except OSError as exc:  # a name too long, no access: one line naming it, not a traceback
        raise RecordError(f"{file}: cannot be read ({exc.strerror or exc})") from None
    if not there:
        raise RecordError(f"{file}: no record here")
    # before the scan: a run lets go of its folder once the file is finished, so a file read after that is whole
    real = file.resolve()  # a link to a run's record (cell1-latest.mcap): the run holds the folder it is in
    writing = folder_lock.holder(real.parent) if real.name == RECORD_FILE else None
    layout = scan(file)
    foreign = not_cellguard(file, layout.topics, layout.schema_names)
    if foreign:
        raise RecordError(foreign)
    record = Record(file, layout, writing)
    if not record.layout.chunks and record.writing:
        raise RecordError(f"{file}: still being written by {record.writing}, no chunk of it yet; wait for its first "
                          f"chunk or for the run to end")
    if not record.layout.chunks:
        problems = "; ".join(d.why for d in record.layout.damage) or "no chunk in the file"
        raise RecordError(f"{file}: nothing can be recovered ({problems})")
    if strict and not (health := record.health()).ok:
        raise RecordError(f"{file}: {health.describe()}")
    return record


def record_file(path: Path | str) -> Path:
    """The record file of ``path``: a run folder's record.mcap, or ``path`` itself. RecordError naming ``path`` if
    it cannot be looked at (a component over 255 bytes, no access: is_dir raises OSError for those; a link loop:
    resolved here, so that the record is named before an output is checked against it)."""
    path = Path(path)
    try:
        file = path / RECORD_FILE if path.is_dir() else path
        file.resolve()
    except (OSError, RuntimeError) as exc:  # RuntimeError: a symlink loop (Python 3.11)
        raise RecordError(f"{path}: cannot be read ({getattr(exc, 'strerror', None) or exc})") from None
    return file


class Record:
    """One record file, read lazily chunk by chunk; see the module docstring for the contract."""

    def __init__(self, file: Path, layout: Layout, writing: str | None = None):
        self.file, self.layout = file, layout
        self.writing = None if layout.finished else writing  # finished: only its index or summary is being written
        self._buf = open_buffer(file)
        self._late_damage: dict[int, str] = {}
        self._unindexed: dict[int, collections.Counter] = {}  # chunk offset -> topic -> messages its indexes leave out
        self._sought: set[int] = set()  # channels whose chunks were all read for messages their indexes leave out
        self._off_schema: dict[str, set[tuple[int, int]]] = {}  # topic -> (log time, sequence) of each bad message
        self._ids = file_ids(layout.topics)  # topic -> id, None: not in the file
        self._contexts: list[ContextChange] | None = None
        self._indexed: dict[int, tuple[int, int | None]] | None = None  # the cycle index's spans, read once
        self._spans: dict[int, tuple[int, int | None]] | None = None  # cycle_spans(), read once
        self.context_loss: str | None = None
        self._facts_note: str | None = None  # the metadata record disagrees with the context (which is used)
        facts = layout.metadata.get("cellguard", {})
        self._stated = {key: facts[key] for key in _NUMBERS if key in facts}  # as written, checked against the context
        stated = _natural(facts.get("record_version"))  # None: lost or malformed
        self.version = stated or 1
        self.record_id: str | None = facts.get("record_id")
        self.epoch_wall_ns = _natural(facts.get("epoch_wall_ns")) or 0
        self.start_ns = _natural(facts.get("start_ns")) or 0
        if facts:
            self._readable()
        self._offset = self.epoch_wall_ns if self.version >= 2 else 0  # log time = record time + offset
        if stated is None and any(c.topic == "/joint_states" for c in layout.channels.values()):
            self._offset, self.version = None, 2  # version 2 (format 1 has no ROS 2 channels), its metadata lost

    def close(self) -> None:
        self._buf.close()

    def __enter__(self) -> Record:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- context --------------------------------------------------------------------------
    @property
    def contexts(self) -> list[ContextChange]:
        """One entry per context change; a periodic repeat stands in for a change whose chunk was lost."""
        if self._contexts is None:
            try:
                self._read_contexts()
            except RecordError:  # a newer format refused: refused again at the next read, not read as no context
                self._contexts = None
                raise
        return self._contexts

    def _read_contexts(self) -> None:
        """The context changes (``contexts``), the record's facts settled by the first (``_settle``)."""
        self._contexts = []
        for m, d in self._json(self._raw(["/context"]), "/context", _context_fits):
            if not self._contexts:
                self._settle(d, m.log_time - d["t_ns"])
            if self._contexts and self._contexts[-1].version == d["version"]:
                continue  # a repeat of the context in force
            self._contexts.append(ContextChange(d["t_ns"], d["version"], tuple(d.get("changed", ())),
                                                d.get("versions", {}), d["context"]))
        saved = _saved_context(self.layout.metadata.get("cellguard.context", {}))
        if not self._contexts and saved:
            self._contexts.append(saved[0])
            self._settle(saved[1], self.epoch_wall_ns)
            self.context_loss = ("the context message is lost or malformed; the context was taken from the "
                                 "copy at the end of the file")
        elif self._contexts and self._contexts[0].t_ns > self.start_ns:
            self.context_loss = (f"the first context chunk is lost; the context was taken from its repeat at "
                                 f"t={self._contexts[0].t_ns * 1e-9:.3f} s")
        elif not self._contexts:
            self.context_loss = "the context is lost (no readable copy)"

    def _settle(self, stated: dict, log_offset: int) -> None:
        """What the first readable context states about the record (its id, format, epoch and start) and so the
        log-time offset: where the metadata record at the file's start was lost (a damaged record read as format 1,
        with no id and spans in wall time), and where it says otherwise (an epoch a year off put every cycle
        outside the ticks read for it). ``log_offset``: its log time less its ``t_ns``, for a context that does
        not state the epoch."""
        self.record_id = stated.get("record_id") or self.record_id
        for key in _NUMBERS:
            if key in stated:
                setattr(self, "version" if key == "record_version" else key, stated[key])
        self._readable()  # a context of a newer format was read with this version's rules, and recovered into a
        # copy this version refused
        if self.version < 2:
            self._offset = 0
        elif "epoch_wall_ns" in stated:
            self._offset = self.epoch_wall_ns
        elif self._offset is None:
            self._offset = log_offset
        found = self.facts()
        wrong = [f"{key} {_shown(written)} (the context: {found[key]})" for key, written in self._stated.items()
                 if key in stated and written != found[key]]
        if wrong:
            self._facts_note = f"the metadata record states {', '.join(wrong)}; the context's values are used"

    def _readable(self) -> None:
        """Refuse a record of a format newer than this cellguard reads, stated by its metadata or its context."""
        if self.version > RECORD_VERSION:
            raise RecordError(f"{self.file}: record format version {self.version} is newer than this cellguard reads "
                              f"(1 to {RECORD_VERSION}); update cellguard")

    def facts(self) -> dict[str, str]:
        """The record's format, epoch and start as read, as metadata text (what a recovered copy states)."""
        return {"record_version": str(self.version), "epoch_wall_ns": str(self.epoch_wall_ns),
                "start_ns": str(self.start_ns)}

    @property
    def start_wall_ns(self) -> int:
        """The wall clock when the record started [ns since 1970]."""
        _ = self.contexts  # a context message states the epoch and the start where the metadata was lost
        return self.epoch_wall_ns + self.start_ns

    @property
    def start_utc(self) -> str | None:
        """When the record started, UTC ISO 8601 to the millisecond; None where the record states no wall clock."""
        wall = self.start_wall_ns  # reads the contexts, which state the epoch where the metadata was lost
        if not self.epoch_wall_ns:
            return None
        return dt.datetime.fromtimestamp(wall * 1e-9, dt.timezone.utc).isoformat(timespec="milliseconds")

    @property
    def context(self) -> dict:
        if not self.contexts:
            raise RecordError(f"{self.file}: the context record is missing or damaged")
        return self.contexts[0].context

    # -- cycles, events, chunks -----------------------------------------------------------
    def cycles(self) -> Iterator[CycleRecord]:
        for _, cycle in self._json(self._whole("/cycles"), "/cycles", _cycle_record):
            if cycle is not None:  # None: a cycle's begin marker
                yield cycle

    def events(self) -> Iterator[EventRecord]:
        """The events; ``cycle`` None for one outside the span of the cycle it is stamped with, as a tick's. Spans are
        closed: a cycle's last tick, and a stop read on it, lie at its end. The recorder stamps an event raised after a
        cycle's end with none, whatever its time (the retreat's first lies at the end); before, it stamped each with the
        cycle begun last, and such a record reads as written but for an event after its cycle's end time."""
        for _, event in self._json(self._whole("/events"), "/events", _event_record):
            span = None if event.cycle is None else self._span(event.cycle)
            if span is not None and not span[0] <= event.t_ns <= (_INT64 if span[1] is None else span[1]):
                event = replace(event, cycle=None)
            yield event

    def cycle_spans(self) -> dict[int, tuple[int, int | None]]:
        """Each cycle the record marks: (t_start_ns, t_end_ns) on the record's clock, t_end_ns None where no end marker
        is read (the run was killed in it, or its chunk was lost). The index's row where the index has the cycle (over
        any marker of it), else the markers (a malformed one skipped); of a cycle in either twice, its last. ``ticks(cycle=)``
        and each tick's and event's cycle take the same span."""
        return dict(self._all_spans())

    def _all_spans(self) -> dict[int, tuple[int, int | None]]:
        """``cycle_spans()``, read once: every /cycles marker (nearly every chunk of the file), the index over them."""
        if self._spans is None:
            marked = {d["cycle"]: (d["t_start_ns"], d.get("t_end_ns"))
                      for _, d in self._json(self._whole("/cycles"), "/cycles", _cycle_marker)}
            self._spans = {**marked, **self._index_spans()}
        return self._spans

    def _span(self, cycle: int) -> tuple[int, int | None] | None:
        """``cycle_spans().get(cycle)``, the markers read only where the index does not have the cycle: a read of a
        window or a cycle costs about the window's, not the whole file's."""
        span = self._index_spans().get(cycle)
        return span if span is not None else self._all_spans().get(cycle)

    def _index_spans(self) -> dict[int, tuple[int, int | None]]:
        """The spans of the cycle index beside the record (``INDEX_DIR/cycles``), every part read once; a part that
        indexes another run or cannot be read is left out (the record's own markers still say)."""
        if self._indexed is None:
            index = self.file.parent / INDEX_DIR
            self._indexed = index_spans(index, self.record_id) if self.file.name == RECORD_FILE else {}
        return self._indexed

    def measurements(self) -> Iterator[Measurement]:
        """The readings in time order; one whose names or sizes differ from the first one's is skipped as
        malformed (the readings of one cell have one layout, and a dataset needs it)."""
        return self._measurements(self.messages(["/measurements"]))

    def _measurements(self, messages: Iterable[Message]) -> Iterator[Measurement]:
        names = None
        for m, reading in self._json(messages, "/measurements", _measurement):
            names = reading.names if names is None else names
            if reading.names != names:
                self._note("/measurements", m)
                continue
            yield reading

    def _json(self, messages: Iterable[Message], topic: str, build: Callable[[dict], object]) -> Iterator[tuple]:
        """(message, ``build(decoded JSON)``) per message, as ``_decoded``."""
        return self._decoded(messages, topic, lambda data: build(loads(data)))

    def _decoded(self, messages: Iterable[Message], topic: str, decode: Callable[[bytes], object]) -> Iterator[tuple]:
        """(message, ``decode(data)``) per message; one that does not decode or fit its schema is skipped and
        noted, and ``health()`` reports it as damage (a reader never stops on a malformed message)."""
        for m in messages:
            try:
                value = decode(m.data)
            except MALFORMED:
                self._note(topic, m)
                continue
            yield m, value

    def _note(self, topic: str, m: Message) -> None:
        """Note a malformed message once, however often it is read."""
        self._off_schema.setdefault(topic, set()).add((m.log_time, m.sequence))

    def chunks(self) -> Iterator[RecordedChunk]:
        for _, chunk in self._decoded(self.messages(["/chunks"]), "/chunks", _recorded_chunk):
            yield chunk

    # -- ticks ----------------------------------------------------------------------------
    def ticks(self, cycle: int | None = None, rate: str = "all", start_ns: int | None = None,
              end_ns: int | None = None) -> Ticks:
        """Ticks of one cycle or a time span; ``all`` merges the full-rate windows into the decimated stream
        (``_TickMerge``), held whole: a batch may reach back before any tick."""
        topics = _tick_topics(rate)
        if cycle is not None:
            start_ns, end_ns = self._cycle_span(cycle)
        span = self._span if cycle is None else {cycle: (start_ns, end_ns)}.get  # ticks of other stamps are left out
        lo = None if start_ns is None else start_ns - self._batch_span_ns()
        hi = {"/ticks/decimated": end_ns,  # a pre-trigger backlog is logged up to one window after its ticks
              "/ticks/full": None if end_ns is None else end_ns + self._backlog_ns()}
        joints, streams = self._named_streams({topic: self.messages([topic], lo, hi[topic]) for topic in topics})
        merge = _TickMerge(joints, span, cycle, start_ns, end_ns)
        for rank, batches in enumerate(streams):  # each read through before the next: malformed ones noted in order
            for batch in batches:
                merge.add(rank, batch)
        return merge.hand_on(None)

    def tick_parts(self, rate: str, rows: int) -> Iterator[Ticks]:
        """The ticks of ``ticks(rate=rate)``, in its order, about ``rows`` values of each field (ticks times joints)
        at a time, one empty part for a record without ticks; ``UnorderedTicks`` where that order cannot be kept.

        The streams are merged by their batches' first times (the recorder writes each stream in time order): a tick
        is handed on once no batch still to come starts at or before it, so only a part and a batch or two are
        held."""
        topics = _tick_topics(rate)
        joints, streams = self._named_streams({topic: self.messages([topic]) for topic in topics})
        merge, heads = _TickMerge(joints, self._span), [next(stream, None) for stream in streams]
        handed, given = None, False  # handed: every tick before it was handed on
        while True:
            live = [(int(head["t_ns"].min()), i) for i, head in enumerate(heads) if head is not None]
            horizon = min(live, default=(None, None))[0]  # no batch still to come starts before it
            if merge.held and (horizon is None or merge.held >= rows / max(1, len(joints))):
                part, handed = merge.hand_on(horizon), horizon
                if len(part):
                    given = True
                    yield part
            if horizon is None:
                break
            i = min(live)[1]
            batch, heads[i] = heads[i], next(streams[i], None)
            if handed is not None and batch["t_ns"].min() < handed:
                raise UnorderedTicks(f"{self.file}: a {topics[i]} batch reaches back before ticks handed on")
            merge.add(i, batch)
        if not given:
            yield merge.hand_on(None)

    def _named_streams(self, streams: dict[str, Iterable[Message]]) -> tuple[tuple[str, ...], list[Iterator[dict]]]:
        """The joints the first decoded batch names (the decimated stream's, else the full-rate one's) and each
        stream's batches that name them and hold a tick; a malformed batch, or one naming other joints, is skipped
        and noted. A stream is read ahead only until a batch names the joints."""
        joints, named = None, []
        for topic, messages in streams.items():
            batches = self._decoded(messages, topic, _tick_batch)
            if joints is None and (first := next(batches, None)) is not None:
                joints, batches = tuple(first[1]["joints"]), itertools.chain([first], batches)
            named.append(self._naming(topic, batches, joints))
        return joints or (), named

    def _naming(self, topic: str, batches: Iterator[tuple], joints: tuple[str, ...] | None) -> Iterator[dict]:
        """The batches that name ``joints`` and hold a tick; one naming others is noted."""
        for m, batch in batches:
            if tuple(batch["joints"]) != joints:
                self._note(topic, m)
            elif len(batch["t_ns"]):
                yield batch

    def _cycle_span(self, cycle: int) -> tuple[int, int | None]:
        """Where a cycle lies in time (``_span``); RecordError if the record does not mark it."""
        span = self._span(cycle)
        if span is None:
            raise RecordError(f"cycle: {cycle} is not in {self.file}")
        return span

    def _batch_span_ns(self) -> int:
        """How far before its log time a tick batch may reach: one chunk of ticks."""
        context = self.contexts[0].context if self.contexts else {}
        return _field(context, "record.chunk_ns", 100_000_000) + _field(context, "servo_period_ns", 1_000_000)

    def _backlog_ns(self) -> int:
        """How far after its ticks a full-rate backlog may be logged: the pre-trigger window and one chunk."""
        context = self.contexts[0].context if self.contexts else {}
        return round(_field(context, "record.pre_trigger_s", 10.0) * 1e9) + self._batch_span_ns()

    def sha256(self) -> str:
        """The sha256 of the bytes this record is read from (the file as it was when opened): a hash of its path
        taken after the read could be another file's, one put in its place meanwhile and taken away."""
        return hashlib.sha256(self._buf).hexdigest()

    def attachment(self, name: str) -> bytes | None:
        """The data of attachment ``name`` (e.g. ``robot_description.urdf``), or None if absent or unreadable."""
        from mcap.records import Attachment

        from cellguard.record.scan import read_attachment

        where = self.layout.attachments.get(name)
        record = None if where is None else read_attachment(self._buf, *where)
        return record.data if isinstance(record, Attachment) else None

    # -- health ---------------------------------------------------------------------------
    def health(self) -> Health:
        """Read every chunk once: CRCs, sequence gaps per channel, message counts, each message checked as its
        reader takes it (``_Checks``), and messages a chunk's message indexes leave out (``_unindex``).

        In file order, a chunk at a time: none of it needs time order, and a merge by time holds every chunk that
        overlaps another (a record whose chunks were written twice held all of them). Only the messages checked are
        taken out of a chunk; the others are counted by their heads."""
        names = {i: t for t, i in self._ids.items() if i is not None}
        last: dict[int, int] = {}
        gaps: dict[str, list[tuple[int, int]]] = {t: [] for t in self._ids}
        counts = dict.fromkeys(self._ids, 0)
        repeats: dict[str, int] = {}
        first_t, last_t = 1 << 64, -1  # log times are u64
        self.contexts  # noqa: B018 - read first, so that a lost context is known
        offset = self._offset or 0
        checks, every = _Checks(self._ids), set(names)
        for i, ref in enumerate(self.layout.chunks):
            if not _overlaps(ref, every, None, None):
                continue
            heads: list[tuple[int, int, int, int]] = []
            for m in self._chunk_messages(ref, checks.channels, heads):
                checks.check(m)
            if ref.channels is not None and not {head[0] for head in heads} <= ref.channels:
                self._unindex(i, heads, names)  # and read by the readers too from now on, as checked here
            for channel, sequence, log_time, _ in heads:
                topic = names.get(channel)
                if topic is None:
                    continue
                counts[topic] += 1
                previous = last.get(channel, 0)
                if sequence <= previous:  # the writer numbers each channel's messages 1, 2, 3, ... in file order
                    repeats[topic] = repeats.get(topic, 0) + 1
                else:
                    if sequence > previous + 1:
                        gaps[topic].append((previous + 1, sequence - 1))
                    last[channel] = sequence
                if log_time < first_t:
                    first_t = log_time
                if log_time > last_t:
                    last_t = log_time
        for topic, keys in checks.malformed().items():  # noted once, however often read
            self._off_schema.setdefault(topic, set()).update(keys)
        damage = ([d.why for d in self.layout.damage if not (self.writing and d.at_end)]  # its end, not written yet
                  + list(self._late_damage.values())
                  + [f"chunk at byte {at}: its message indexes leave out "
                     f"{', '.join(f'{n} {topic}' for topic, n in left.items())} message(s), which a read by the "
                     f"indexes alone skips (read from the chunk itself here)"
                     for at, left in self._unindexed.items()]
                  + [f"{len(bad)} {topic} message(s) off their schema, skipped"
                     for topic, bad in self._off_schema.items()]
                  + [f"{n} {topic} message(s) repeat an earlier sequence number" for topic, n in repeats.items()])
        damaged = len(self._late_damage) + sum("chunk at byte" in d.why for d in self.layout.damage)
        return Health(self.layout.finished, self.layout.truncated, len(self.layout.chunks) - len(self._late_damage),
                      damaged, tuple(damage), {t: tuple(g) for t, g in gaps.items()}, counts,
                      None if last_t < 0 else (first_t - offset, last_t - offset), self.context_loss,
                      {topic: len(bad) for topic, bad in self._off_schema.items()},
                      self.layout.metadata.get("cellguard.recovered", {}).get("source_health"), self._facts_note,
                      repeats, self.writing, dict(sum(self._unindexed.values(), collections.Counter())))

    def _unindex(self, i: int, heads: list[tuple[int, int, int, int]], names: dict[int, str]) -> None:
        """Chunk ``i`` holds messages of channels its message indexes leave out (an index removed from an edited or
        cut file): every read by the indexes, the mcap package's too, skips them. Noted as damage, and the chunk read
        for them from now on (a recovered copy holds them)."""
        ref = self.layout.chunks[i]
        self._unindexed[ref.offset] = collections.Counter(names.get(channel, f"channel {channel}")
                                                          for channel, *_ in heads if channel not in ref.channels)
        self.layout.chunks[i] = replace(ref, channels=ref.channels | {channel for channel, *_ in heads})

    def _whole(self, topic: str) -> list[Message]:
        """Every message of a small topic (/events, /cycles) by log time. Where fewer are read than the file holds (its
        statistics' count, else the highest sequence number read: the writer numbers each channel 1, 2, 3, ...), the
        chunks whose indexes do not list the topic are read once for messages they leave out (``_unindex``): every
        reader of the events, not only one that ran ``health``, reads them. A record read whole costs a few ms more."""
        messages = list(self.messages([topic]))
        channel = self._ids[topic]
        if channel is None or channel in self._sought:
            return messages
        self._sought.add(channel)
        held = max((self.layout.counts or {}).get(channel, 0), max((m.sequence for m in messages), default=0))
        if len({m.sequence for m in messages}) >= held:
            return messages
        names, found = {i: t for t, i in self._ids.items() if i is not None}, False
        for i, ref in enumerate(self.layout.chunks):
            if ref.channels is not None and channel not in ref.channels:
                heads: list[tuple[int, int, int, int]] = []
                self._chunk_messages(ref, set(), heads)
                if channel in {head[0] for head in heads}:
                    self._unindex(i, heads, names)
                    found = True
        return list(self.messages([topic])) if found else messages

    # -- raw messages ---------------------------------------------------------------------
    def channel_id(self, topic: str) -> int | None:
        """The id of ``topic``'s channel in this file, by its own channel records (``file_ids``); None: not in it."""
        return self._ids[topic]

    def messages(self, topics: list[str], start_ns: int | None = None, end_ns: int | None = None
                 ) -> Iterator[Message]:
        """Raw MCAP messages of ``topics`` from every readable chunk overlapping the span (record clock), by log time.

        Log times are wall-clock ns since 1970 from version 2 on: ``log_time - rec.epoch_wall_ns``
        is the record clock (for a backlog logged late, ``publish_time`` is).
        """
        unknown = set(topics) - set(self._ids)
        if unknown:
            raise RecordError(f"topics: {', '.join(sorted(unknown))} not in a cellguard record; "
                              f"known: {', '.join(self._ids)}")
        self.contexts  # noqa: B018 - the first readable context settles the log-time offset
        offset = self._offset or 0
        return self._raw(topics, None if start_ns is None else start_ns + offset,
                         None if end_ns is None else end_ns + offset)

    def _raw(self, topics: list[str], start_ns: int | None = None, end_ns: int | None = None) -> Iterator[Message]:
        """The messages by log time, holding only those not yet due: chunks are opened in order of their first
        time, and a message is passed on once no chunk still to open can hold an earlier one (a record's chunks
        follow each other, so that is one chunk or two, however long the record)."""
        wanted = {self._ids[t] for t in topics} - {None}
        refs = sorted((ref for ref in self.layout.chunks if _overlaps(ref, wanted, start_ns, end_ns)),
                      key=lambda ref: (ref.start_ns, ref.offset))
        pending: list[Message] = []  # by log time; file order within equal times
        for ref in refs:
            due = bisect.bisect_left(pending, ref.start_ns, key=_log_time)
            yield from pending[:due]
            del pending[:due]
            pending += self._chunk_messages(ref, wanted)
            pending.sort(key=_log_time)
        yield from pending

    def _chunk_messages(self, ref: ChunkRef, wanted: set[int], heads: list | None = None) -> list[Message]:
        """The messages of ``wanted`` channels in one chunk (and into ``heads`` every message's, as ``read_chunk``);
        none if it is damaged (noted for ``health()``)."""
        if ref.offset in self._late_damage:
            return []
        try:
            return read_chunk(self._buf, ref, wanted, heads)
        except RecordError as exc:
            self._late_damage[ref.offset] = str(exc)
            return []


class _Checks:
    """The messages ``cycles()``, ``events()``, ``measurements()``, ``chunks()`` and ``ticks()`` skip as malformed,
    found in one read of the file in file order (``health``): each message decoded as its reader decodes it, a
    reading whose names differ from the first reading's and a tick batch naming other joints than the first
    decimated batch (else the first full-rate one: ``_named_streams``, which reads each stream by time) included."""

    _TOPICS = ("/cycles", "/events", "/measurements", "/chunks", *_TICK_TOPICS.values())  # the order readers note in

    def __init__(self, ids: dict[str, int]):
        decoders = (lambda data: _cycle_record(loads(data)), lambda data: _event_record(loads(data)),
                    lambda data: _measurement(loads(data)), _recorded_chunk, _tick_batch, _tick_batch)
        self._by_id: dict[int, list[tuple[str, Callable[[bytes], object]]]] = {}
        for topic, decode in zip(self._TOPICS, decoders):
            if ids[topic] is not None:
                self._by_id.setdefault(ids[topic], []).append((topic, decode))
        self.channels = set(self._by_id)  # the channel ids of the messages to check
        self._bad: dict[str, list[tuple[int, int]]] = {topic: [] for topic in self._TOPICS}  # (log time, sequence)
        self._names: tuple[str, ...] | None = None  # the first reading's
        self._joints: tuple[str, ...] | None = None  # the first decimated batch's: what every tick batch must name
        self._waiting: dict[tuple[str, ...], list[tuple[int, int]]] | None = {}  # full-rate batches read before
        # any decimated one, by the joints they name (None once one is read; the recorder writes it first)

    def check(self, m: Message) -> None:
        for topic, decode in self._by_id.get(m.channel_id, ()):
            try:
                value = decode(m.data)
            except MALFORMED:
                self._bad[topic].append((m.log_time, m.sequence))  # as ``_decoded`` skips it
                continue
            if topic == "/measurements":
                self._names = value.names if self._names is None else self._names
                if value.names != self._names:
                    self._bad[topic].append((m.log_time, m.sequence))
            elif topic in _TICK_TOPICS.values():
                self._batch(topic, tuple(value["joints"]), (m.log_time, m.sequence))

    def _batch(self, topic: str, joints: tuple[str, ...], key: tuple[int, int]) -> None:
        if topic == _TICK_TOPICS["full"] and self._waiting is not None:
            self._waiting.setdefault(joints, []).append(key)
            return
        if self._waiting is not None:  # the first decimated batch: it names the joints
            self._joints, waiting, self._waiting = joints, self._waiting, None
            self._bad[_TICK_TOPICS["full"]] += [k for named, keys in waiting.items() if named != joints for k in keys]
        elif joints != self._joints:
            self._bad[topic].append(key)

    def malformed(self) -> dict[str, list[tuple[int, int]]]:
        """Topic -> (log time, sequence) of each malformed message, topics in the order the readers note them."""
        if self._waiting:  # no decimated batch: the first full-rate one names the joints
            first, waiting, self._waiting = next(iter(self._waiting)), self._waiting, None
            self._bad[_TICK_TOPICS["full"]] += [k for named, keys in waiting.items() if named != first for k in keys]
        return {topic: keys for topic, keys in self._bad.items() if keys}


def _log_time(m: Message) -> int:
    return m.log_time


_NUMBERS = ("record_version", "epoch_wall_ns", "start_ns")  # what a context states as numbers about its record
_VERSIONS = ("policy_version", "calibration_version", "datum_version", "context_version")  # a cycle's stamps
_INT64 = 2**63  # the ns stamps are int64: a larger one overflows Parquet, dates and numpy


def _shown(value: object, limit: int = 40) -> str:
    """``value`` as its repr, cut to ``limit`` characters with the length said (a 5,000-digit field filled the warning)."""
    text = repr(value)
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text):,} characters)"


def _natural(text: str | None) -> int | None:
    """A count as metadata text states it (ASCII digits, below 2^63), else None: ``"²".isdigit()`` holds, and
    ``int("²")`` raises; so does ``int`` of more than 4,300 digits (every reader of such a record failed, recover
    included), hence the length first."""
    return (int(text) if text and len(text) <= 19 and text.isascii() and text.isdigit() and int(text) < _INT64
            else None)


def _saved_context(saved: dict[str, str]) -> tuple[ContextChange, dict] | None:
    """The context from the ``cellguard.context`` metadata record written at close, and the numbers it states
    about the record; None if there is none or it is malformed as a context message would be."""
    from cellguard.record.context import versions

    try:
        context = _context_types(loads(saved["context"]))
    except (KeyError, ValueError, TypeError):
        return None
    t_ns = _natural(saved.get("t_ns", "0"))
    if t_ns is None:
        return None
    stamps = versions(context)
    stated = {key: _natural(saved.get(key)) for key in _NUMBERS}
    return (ContextChange(t_ns, stamps["context_version"], tuple(sorted(context)), stamps, context),
            {key: value for key, value in stated.items() if value is not None} | {"record_id": saved.get("record_id")})


def index_spans(index: Path, record_id: str | None) -> dict[int, tuple[int, int]]:
    """{cycle: (t_start_ns, t_end_ns)} of the cycle index in ``index`` (a run folder's ``INDEX_DIR``), its parts in
    name order (``_index_part``): the spans ``Record.events`` and ``record query`` place events by."""
    spans: dict[int, tuple[int, int]] = {}
    if (index / "cycles").is_dir():
        for part in sorted((index / "cycles").glob("day=*/*.parquet")):
            spans.update(_index_part(part, record_id))
    return spans


def _index_part(part: Path, record_id: str | None) -> dict[int, tuple[int, int]]:
    """{cycle: (t_start_ns, t_end_ns)} of one part of the cycle index, of a cycle in it twice the last row; none if
    the part cannot be read or is not this record's: a record with an id takes only parts that name it (both writers
    name it; an unnamed part beside it, an older run's left by a killed ``--overwrite``, put cycles it never had in
    every read). A row is checked as a marker is (a count, stamps, an end not before its start: a row is written at
    its cycle's end); one that is not is left to the markers. Opened by handle: pyarrow takes a path only as UTF-8 text, and a FIFO is never opened."""
    if not part.is_file():
        return {}
    try:
        with pa.OSFile(os.fsencode(part)) as f:
            table = pq.read_table(f, columns=["cycle", "t_start_ns", "t_end_ns"])
    except (pa.ArrowException, OSError):
        return {}
    if record_id and indexed_run(table.schema) != record_id:
        return {}
    columns = (table[name].to_pylist() for name in ("cycle", "t_start_ns", "t_end_ns"))
    return {cycle: (start, end) for cycle, start, end in zip(*columns)
            if _is_count(cycle) and _is_stamp(start) and _is_stamp(end) and end >= start}


def _overlaps(ref: ChunkRef, wanted: set[int], start_ns: int | None, end_ns: int | None) -> bool:
    if ref.channels is not None and not (ref.channels & wanted):
        return False
    if start_ns is not None and ref.end_ns < start_ns:
        return False
    return end_ns is None or ref.start_ns <= end_ns


def _tick_topics(rate: str) -> list[str]:
    """The tick streams ``rate`` reads, the decimated first; RecordError for another rate."""
    if rate not in RATES:
        raise RecordError(f"rate: {rate!r} is not one of {', '.join(RATES)}")
    return [topic for name, topic in _TICK_TOPICS.items() if rate in (name, "all")]


class _TickMerge:
    """Tick batches merged into one series by time, held until handed on. Of ticks at one time the decimated
    stream's (rank 0), then the one added first, is kept; ticks outside ``cycle`` (or else the span) are left out
    before that, so a copy of a tick in another cycle does not hide the one in it. A tick's cycle is its stamp where
    it lies in that cycle's span (``span(stamp)``: ``Record._span``), else ``NO_CYCLE``."""

    def __init__(self, joints: tuple[str, ...], span: Callable[[int], tuple[int, int | None] | None],
                 cycle: int | None = None, start_ns: int | None = None, end_ns: int | None = None):
        self.joints, self._span_of, self._cycle, self._span = joints, span, cycle, (start_ns, end_ns)
        self._pending: list[tuple[np.ndarray, ...]] = []  # (t, order, cycle, *fields (n, dof) as written)
        self._added = [0] * len(_TICK_TOPICS)  # ticks added of each rank: with the rank, their order at equal times
        self.held = 0  # ticks held

    def add(self, rank: int, batch: dict) -> None:
        """Hold the ticks of a decoded batch naming ``joints``."""
        n = len(batch["t_ns"])
        order = (rank << 62) + np.arange(self._added[rank], self._added[rank] + n)
        self._added[rank] += n
        dof = len(self.joints)
        self._pending.append((batch["t_ns"], order, batch["cycle"], *(batch[f].reshape(n, dof) for f in TICK_FIELDS)))
        self.held += n

    def hand_on(self, before: int | None) -> Ticks:
        """The held ticks before ``before`` (all for None) by time, one per time; the others stay held."""
        dof = len(self.joints)
        if not self._pending:
            return Ticks(self.joints, np.zeros(0, np.int64), np.zeros(0, np.int64),
                         **{f: np.zeros((0, dof)) for f in TICK_FIELDS})
        t, order, cycle, *values = (np.concatenate(column) for column in zip(*self._pending))
        cycle = _placed(t, cycle, self._span_of)
        keep = self._keep(t, cycle)
        if keep is not None:
            t, order, cycle, values = t[keep], order[keep], cycle[keep], [v[keep] for v in values]
        by_time = np.lexsort((order, t))
        due = by_time if before is None else by_time[t[by_time] < before]
        first = np.ones(len(due), dtype=bool)
        first[1:] = t[due][1:] != t[due][:-1]
        due = due[first]
        rest = np.zeros(0, np.int64) if before is None else by_time[t[by_time] >= before]
        self._pending = [tuple(c[rest] for c in (t, order, cycle, *values))] if len(rest) else []
        self.held = len(rest)
        return Ticks(self.joints, t[due], cycle[due],
                     **{f: v[due].astype(np.float64) for f, v in zip(TICK_FIELDS, values)})

    def _keep(self, t: np.ndarray, cycle: np.ndarray) -> np.ndarray | None:
        """Which ticks are of the cycle, else of the span; None: all."""
        if self._cycle is not None:
            return cycle == self._cycle
        start, end = self._span
        if start is None and end is None:
            return None
        return (t >= (-_INT64 if start is None else start)) & (t <= (_INT64 - 1 if end is None else end))


def _placed(t: np.ndarray, stamps: np.ndarray, span: Callable[[int], tuple[int, int | None] | None]) -> np.ndarray:
    """Each tick's cycle (int64): its stamp, or ``NO_CYCLE`` where it lies outside the span of the cycle it is stamped
    with (a stamp with no span, its markers lost, is kept: nothing says otherwise). Each distinct stamp is looked up
    once and its bounds spread to its ticks by ``np.unique``'s inverse: O(n log n), not a pass per stamp."""
    placed = stamps.astype(np.int64)
    distinct, which = np.unique(placed, return_inverse=True)
    spans = [span(int(stamp)) or (-_INT64, None) for stamp in distinct]
    start = np.array([lo for lo, _ in spans], np.int64)[which]
    end = np.array([_INT64 - 1 if hi is None else hi for _, hi in spans], np.int64)[which]
    return np.where((t < start) | (t > end), NO_CYCLE, placed)


def _tick_batch(data: bytes) -> dict:
    """One /ticks message; ValueError unless it holds one time and cycle per tick and one value per tick and joint."""
    d = TICKS.decode(data)
    n, dof = len(d["t_ns"]), len(d["joints"])
    if len(d["cycle"]) != n or any(d[f].size != n * dof for f in TICK_FIELDS):
        raise ValueError("tick batch: arrays of different lengths")
    return d


def _recorded_chunk(data: bytes) -> RecordedChunk:
    """One /chunks message; ValueError unless its actions fill whole rows of ``dof`` joints (dof 0: the policy
    returned no 2-D array, recorded flat as it came, read as one column)."""
    d = CHUNK.decode(data)
    dof = max(int(d["dof"]), 1)
    actions = d["actions"].astype(np.float64)
    if actions.size % dof:
        raise ValueError("chunk: actions are not whole rows of dof")
    u = d["uncertainty"].astype(np.float64)
    return RecordedChunk(d["t_obs_ns"], d["t_received_ns"], d["latency_ns"], d["dt_ns"],
                         actions.reshape(-1, dof), u if u.size else None)


def _measurement(d: dict) -> Measurement:
    """A /measurements message; TypeError unless its readings are flat arrays of numbers."""
    cycle, readings = d.get("cycle"), d["measurements"]
    if not (isinstance(d["t_ns"], int) and (cycle is None or isinstance(cycle, int)) and isinstance(readings, dict)):
        raise TypeError("measurement")
    names, values = [], []
    for key, array in readings.items():
        if not (isinstance(array, list) and all(isinstance(x, int | float) and not isinstance(x, bool) for x in array)):
            raise TypeError("measurement")
        names += [f"{key}.{i}" for i in range(len(array))]
        values += array
    return Measurement(d["t_ns"], cycle, tuple(names), np.array(values, dtype=np.float64))


def _field(context: dict, path: str, default=None):
    """The context's field at a dotted ``path`` (``record.chunk_ns``), or ``default`` where it or a parent is absent
    or null; a parent that is not a dict raises AttributeError (``_CONTEXT_TYPES`` checks parents first)."""
    for key in path.split("."):
        context = (context or {}).get(key)
    return default if context is None else context


def _is_count(value) -> bool:
    """An int64 count of ns (or a format version): an int, not a bool, in [0, 2^63)."""
    return isinstance(value, int) and not isinstance(value, bool) and 0 <= value < _INT64


def _is_amount(value) -> bool:
    """Seconds or hertz: a number, not a bool, in [0, 1e9) (so that it stays an int64 count of ns)."""
    return isinstance(value, int | float) and not isinstance(value, bool) and 0 <= value < 1e9


# the context's fields that readers use, by dotted path (a parent before its fields), and their types or tests:
# absent or None is allowed, anything else is a malformed context (`cell: 5` made `record info` and
# `to-lerobot` stop with a traceback)
_CONTEXT_TYPES = {
    "site": str, "cell_id": str, "cell": str, "mount": str, "servo_period_ns": _is_count, "policy": dict,
    "embodiment": dict, "embodiment.robot": str, "embodiment.calibration": dict, "embodiment.calibration_dates": list,
    "scenario": dict, "software": dict, "record": dict, "record.chunk_ns": _is_count,
    "record.decimated_hz": _is_amount, "record.pre_trigger_s": _is_amount,
}


def _context_fits(d: dict) -> dict:
    """A context message as written (KeyError/TypeError if it is not one): its context as ``_context_types``,
    and the record's id as text and its format, epoch and start as int64 counts, where it states them."""
    if not (isinstance(d["t_ns"], int) and isinstance(d["version"], str | int) and isinstance(d["context"], dict)
            and all(_is_count(d[key]) for key in _NUMBERS if key in d) and isinstance(d.get("record_id") or "", str)):
        raise TypeError("context message")
    _context_types(d["context"])
    return d


def _context_types(context: dict) -> dict:
    """``context`` if each field in ``_CONTEXT_TYPES`` it has is of its type or passes its test (and the
    calibration dates are text); TypeError if not."""
    if not isinstance(context, dict):
        raise TypeError("context")
    for path, kind in _CONTEXT_TYPES.items():
        value = _field(context, path)
        if value is not None and not (isinstance(value, kind) if isinstance(kind, type) else kind(value)):
            raise TypeError(f"context: {path}")
    if not all(isinstance(date, str) for date in (context.get("embodiment") or {}).get("calibration_dates") or ()):
        raise TypeError("context: embodiment.calibration_dates")
    return context


def _is_stamp(value) -> bool:
    """A time in int64 ns: an int, not a bool, in [-2^63, 2^63)."""
    return isinstance(value, int) and not isinstance(value, bool) and -_INT64 <= value < _INT64


def _is_reading(value) -> bool:
    """A number or null, as an event's asked and sent values are (not a bool, not text such as "nan")."""
    return value is None or isinstance(value, int | float) and not isinstance(value, bool)


def _cycle_marker(d: dict) -> dict:
    """A cycle marker whose number, times and versions fit the index's columns (TypeError if not: a cycle
    10^30 overflowed int64 and a version 5 was no text, and `record recover` stopped half-way)."""
    fits = (_is_count(d["cycle"]) and _is_stamp(d["t_start_ns"])
            and (d.get("t_end_ns") is None or _is_stamp(d["t_end_ns"]))
            and all(isinstance(d.get(k, ""), str) for k in _VERSIONS))
    if not fits:
        raise TypeError("cycle marker")
    return d


def _cycle_record(d: dict) -> CycleRecord | None:
    """A cycle's end marker as a CycleRecord; None for a begin marker."""
    if _cycle_marker(d)["marker"] != "end":
        return None
    if not _is_stamp(d["t_end_ns"]):
        raise TypeError("cycle end marker")
    features = {k: math.nan if v is None else float(v) for k, v in d.get("features", {}).items()}
    versions = {k: d[k] for k in _VERSIONS if k in d}
    return CycleRecord(d["cycle"], str(d["phase"]), d["t_start_ns"], d["t_end_ns"], bool(d["success"]),
                       features, dict(d.get("outcome", {})), versions)


def _event_record(d: dict) -> EventRecord:
    """An event whose fields are of the types ``EventRecord`` states (TypeError if not: the index stores them)."""
    category, cycle = d.get("category"), d.get("cycle")
    fits = (_is_stamp(d["t_ns"]) and isinstance(d["kind"], str)
            and (category is None or _is_count(category) and category <= 2)
            and isinstance(d.get("joint") or "", str) and _is_reading(d.get("asked")) and _is_reading(d.get("sent"))
            and (cycle is None or _is_count(cycle)))
    if not fits:
        raise TypeError("event")
    recovery = d.get("recovery")
    return EventRecord(d["t_ns"], d["kind"], str(d["reason"]), d.get("category"), d.get("joint"),
                       d.get("asked"), d.get("sent"), d.get("cycle"), recovery if isinstance(recovery, dict) else None)
