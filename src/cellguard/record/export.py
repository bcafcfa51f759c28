"""Ticks as a long table (one row per tick and joint) for spreadsheets and other tools.

Written a part at a time: the whole table of a day's record took four times the record's size in memory."""

from __future__ import annotations

import contextlib
import itertools
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import BinaryIO

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from cellguard.errors import RecordError
from cellguard.output import atomic_file
from cellguard.record.reader import _TICK_TOPICS, RATES, Record, Ticks, _tick_batch
from cellguard.record.schemas import TICK_FIELDS

SUFFIXES = {"csv": (".csv",), "parquet": (".parquet", ".pq")}  # the formats written, and the file names that say them
PART_ROWS = 1 << 16  # rows handed to the writer at a time: about 4.5 MB of table, one Parquet row group


def check_format(output: Path, fmt: str) -> None:
    """RecordError unless ``fmt`` is a format written here and the name ``output`` says no other: ``-o t.parquet``
    without ``--format parquet`` wrote CSV into it, which every Parquet reader then refused."""
    if fmt not in SUFFIXES:
        raise RecordError(f"--format: {fmt!r} is not one of {', '.join(SUFFIXES)}")
    suffix = Path(output).suffix.lower()
    named = next((other for other, suffixes in SUFFIXES.items() if suffix in suffixes), fmt)
    if named != fmt:
        raise RecordError(f"-o {output}: a {suffix} file is {named}, but --format is {fmt}; give --format {named}, "
                          f"or a name ending in {SUFFIXES[fmt][0]}")


def ticks_table(ticks: Ticks) -> pa.Table:
    """Columns t_ns, cycle, joint, q_ref, q_cmd, q_meas, qd_meas, effort, current; SI units."""
    n, dof = len(ticks), len(ticks.joints)
    columns = {
        "t_ns": pa.array(np.repeat(ticks.t_ns, dof)),
        "cycle": pa.array(np.repeat(ticks.cycle, dof)),
        "joint": pa.DictionaryArray.from_arrays(np.tile(np.arange(dof, dtype=np.int32), n), list(ticks.joints)),
    }
    for name in TICK_FIELDS:
        columns[name] = pa.array(getattr(ticks, name).reshape(-1))
    return pa.table(columns)


def write_ticks(rec: Record, output: Path, fmt: str, rate: str = "all", cycle: int | None = None) -> int:
    """Write ``rec.ticks(cycle=cycle, rate=rate)`` as csv or parquet (beside the target, then renamed), the whole
    record a part at a time; the number of rows written.

    The caller checks ``output`` first with ``refuse_output`` and ``check_format``, before the ticks are read.
    """
    output = Path(output)
    if rate not in RATES or fmt not in SUFFIXES:  # as rec.ticks refuses a rate (a part-wise read found no stream)
        raise RecordError(f"rate {rate!r}, format {fmt!r}: the rates are {', '.join(RATES)}, the formats "
                          f"{', '.join(SUFFIXES)}")
    if cycle is not None:  # a cycle's ticks: one part
        return _write(iter([rec.ticks(cycle=cycle, rate=rate)]), output, fmt)
    try:
        return _write(tick_parts(rec, rate), output, fmt)
    except _Unordered:  # not as the recorder writes (a crafted file): read whole and sorted, as rec.ticks does
        return _write(iter([rec.ticks(rate=rate)]), output, fmt)


class _Unordered(Exception):
    """A tick batch reaches back before ticks already handed on."""


def tick_parts(rec: Record, rate: str = "all") -> Iterator[Ticks]:
    """The ticks of ``rec.ticks(rate=rate)``, in its order, about ``PART_ROWS`` rows at a time (one empty part for a
    record without ticks); ``_Unordered`` where that order cannot be kept.

    The streams are merged by their batches' first times (the recorder writes each stream in time order): a tick is
    handed on once no batch still to come starts at or before it, so only a part and a batch or two are held. As in
    ``rec.ticks``, the first batch (decimated before full-rate) names the joints, a batch naming others is skipped,
    and of ticks at one time the decimated stream's, then the earliest read, is kept."""
    topics = [topic for name, topic in _TICK_TOPICS.items() if rate in (name, "all")]
    decoded = [rec._decoded(rec.messages([topic]), topic, _tick_batch) for topic in topics]
    firsts = [next(batches, None) for batches in decoded]
    named = next((first[1]["joints"] for first in firsts if first is not None), ())
    streams = [_matching(rec, topic, itertools.chain([first] if first else [], batches), named)
               for topic, first, batches in zip(topics, firsts, decoded)]
    joints, heads = tuple(named), [next(stream, None) for stream in streams]
    taken = [0] * len(streams)  # ticks taken from each stream: with its rank, their order at equal times
    pending: list[tuple[np.ndarray, ...]] = []  # (t, order, cycle, values (n, fields, dof)) of ticks not handed on
    held, handed, given = 0, None, False  # handed: every tick before it was handed on
    while True:
        live = [(int(head["t_ns"].min()), i) for i, head in enumerate(heads) if head is not None]
        horizon = min(live, default=(None, None))[0]  # no batch still to come starts before it
        if pending and (horizon is None or held >= PART_ROWS / max(1, len(joints))):
            part, pending = _hand_on(pending, horizon, joints)
            held, handed = sum(len(p[0]) for p in pending), horizon
            if len(part):
                given = True
                yield part
        if horizon is None:
            break
        i = min(live)[1]
        batch, heads[i] = heads[i], next(streams[i], None)
        t = batch["t_ns"]
        if handed is not None and t.min() < handed:
            raise _Unordered
        values = np.stack([batch[f].reshape(len(t), len(joints)) for f in TICK_FIELDS], axis=1)
        pending.append((t, (i << 62) + np.arange(taken[i], taken[i] + len(t)), batch["cycle"],
                        values.astype(np.float64)))
        taken[i] += len(t)
        held += len(t)
    if not given:
        yield Ticks(joints, np.zeros(0, np.int64), np.zeros(0, np.int64),
                    **{f: np.zeros((0, len(joints))) for f in TICK_FIELDS})


def _matching(rec: Record, topic: str, decoded: Iterator[tuple], joints) -> Iterator[dict]:
    """The batches that name ``joints`` and hold a tick; one naming others is noted as ``rec.ticks`` notes it."""
    for message, batch in decoded:
        if batch["joints"] != joints:
            rec._note(topic, message)
        elif len(batch["t_ns"]):
            yield batch


def _hand_on(pending: list[tuple[np.ndarray, ...]], before: int | None, joints: tuple[str, ...]
             ) -> tuple[Ticks, list[tuple[np.ndarray, ...]]]:
    """The pending ticks before ``before`` (all for None) by time, one per time, and those still pending."""
    t, order, cycle, values = (np.concatenate(column) for column in zip(*pending))
    by_time = np.lexsort((order, t))
    due = by_time if before is None else by_time[t[by_time] < before]
    first = np.ones(len(due), dtype=bool)
    first[1:] = t[due][1:] != t[due][:-1]
    due = due[first]
    part = Ticks(joints, t[due], cycle[due].astype(np.int64),
                 **{f: values[due, k] for k, f in enumerate(TICK_FIELDS)})
    rest = np.zeros(0, np.int64) if before is None else by_time[t[by_time] >= before]
    return part, [tuple(column[rest] for column in (t, order, cycle, values))] if len(rest) else []


def _write(parts: Iterator[Ticks], output: Path, fmt: str) -> int:
    """Write the parts' tables into one file (beside ``output``, then renamed); the number of rows written. The
    first part is read before the file is made: a record that cannot be read leaves nothing behind."""
    tables = (ticks_table(part) for part in parts)
    first = next(tables)
    rows = 0
    try:
        with atomic_file(output, "-o") as f, _writer(f, fmt, first.schema) as write:
            for table in itertools.chain([first], tables):
                write(table)
                rows += table.num_rows
    except pa.ArrowException as exc:
        raise RecordError(f"-o {output}: cannot write ({exc})") from None
    return rows


@contextlib.contextmanager
def _writer(f: BinaryIO, fmt: str, schema: pa.Schema) -> Iterator[Callable[[pa.Table], None]]:
    """``write(table)`` appending to ``f``: CSV's header before the first table, Parquet's footer after the last."""
    if fmt == "parquet":  # dictionary pages only where values repeat: on the floats, each part's row group
        # started a dictionary anew and a 178 MB record's file grew from 106 MB (one whole table) to 149 MB (89 MB now)
        with pq.ParquetWriter(f, schema, compression="zstd", use_dictionary=["joint", "cycle"]) as writer:
            yield writer.write_table
        return
    header = True

    def write(table: pa.Table) -> None:
        nonlocal header
        pacsv.write_csv(table.set_column(2, "joint", table["joint"].cast(pa.string())), f,
                        pacsv.WriteOptions(include_header=header))
        header = False

    yield write
