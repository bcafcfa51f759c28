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
from cellguard.record.outputs import OwnKind, starts_with
from cellguard.record.reader import NO_CYCLE, RATES, Record, Ticks, UnorderedTicks
from cellguard.record.schemas import TICK_FIELDS

SUFFIXES = {"csv": (".csv",), "parquet": (".parquet", ".pq")}  # the formats written, and the file names that say them
PART_ROWS = 1 << 16  # rows handed to the writer at a time: about 4.5 MB of table, one Parquet row group
COLUMNS = ("t_ns", "cycle", "joint", *TICK_FIELDS)
PARQUET_MARK = {b"cellguard": b"ticks export"}  # in a Parquet export's schema metadata: ``-o`` replaces only those


def _parquet_export(f: BinaryIO) -> bool:
    """Whether ``f`` is a Parquet file whose schema metadata carries ``PARQUET_MARK``."""
    try:
        metadata = pq.read_schema(f).metadata or {}
    except (pa.ArrowException, OSError):  # not Parquet (a damaged footer raises OSError: "Couldn't deserialize")
        return False
    return all(metadata.get(k) == v for k, v in PARQUET_MARK.items())


# what ``-o`` of each format replaces: a CSV that begins with the export's header, a Parquet file marked as one
OWN_KINDS = {"csv": OwnKind("a CSV ticks export", starts_with(",".join(f'"{c}"' for c in COLUMNS).encode() + b"\n")),
             "parquet": OwnKind("a Parquet ticks export", _parquet_export,
                                "; one by a cellguard before November 2026 carries no mark and is refused too")}


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
    """Columns t_ns, cycle, joint, q_ref, q_cmd, q_meas, qd_meas, effort, current; SI units. ``cycle`` is null for a
    tick between cycles (``NO_CYCLE``: a retreat, a stop's settling)."""
    n, dof = len(ticks), len(ticks.joints)
    cycle = np.repeat(ticks.cycle, dof)
    columns = {
        "t_ns": pa.array(np.repeat(ticks.t_ns, dof)),
        "cycle": pa.array(cycle, mask=cycle == NO_CYCLE),
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
    if rate not in RATES or fmt not in SUFFIXES:  # both in one refusal, before anything is read
        raise RecordError(f"rate {rate!r}, format {fmt!r}: the rates are {', '.join(RATES)}, the formats "
                          f"{', '.join(SUFFIXES)}")
    if cycle is not None:  # a cycle's ticks: one part
        return _write(iter([rec.ticks(cycle=cycle, rate=rate)]), output, fmt)
    try:
        return _write(rec.tick_parts(rate, PART_ROWS), output, fmt)
    except UnorderedTicks:  # not as the recorder writes (a crafted file): read whole and sorted, as rec.ticks does
        return _write(iter([rec.ticks(rate=rate)]), output, fmt)


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
        with pq.ParquetWriter(f, schema.with_metadata(PARQUET_MARK), compression="zstd",
                              use_dictionary=["joint", "cycle"]) as writer:
            yield writer.write_table
        return
    header = True

    def write(table: pa.Table) -> None:
        nonlocal header
        pacsv.write_csv(table.set_column(2, "joint", table["joint"].cast(pa.string())), f,
                        pacsv.WriteOptions(include_header=header))
        header = False

    yield write
