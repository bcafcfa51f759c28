"""The index for long histories: one Parquet row per cycle and per event, partitioned by day.

The MCAP file is the record; the index is derived from it (``record recover`` rebuilds it) and
exists so that a question over a month of cycles reads one row per cycle instead of rescanning
ticks. Rows arrive in time order and are written in parts (``index/cycles/day=YYYY-MM-DD/
part-NNNNNNNN.parquet``), so files stay time-sorted and a query can skip whole days. Each row is
stamped with the context versions (policy, calibration, datum) it was recorded under, and each part
names the run it indexes (``RECORD_ID_KEY`` in its Parquet metadata), so an index copied beside
another run's record is refused rather than read as that run's.
"""

from __future__ import annotations

import datetime as dt
import math
import re
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

import duckdb
import pyarrow as pa
import pyarrow.dataset as ds
import pyarrow.fs as pafs
import pyarrow.parquet as pq

from cellguard.dates import utc_day
from cellguard.errors import RecordError

TABLES = ("cycles", "events")
RECORD_ID_KEY = b"cellguard.record_id"  # a part's Parquet metadata: the record id of the run it indexes
PART_GLOB = "day=*/part-*.parquet"  # the parts of one table of the index, under its folder
_BASE_TYPES = {
    "cycle": pa.int64(), "phase": pa.string(), "t_start_ns": pa.int64(), "t_end_ns": pa.int64(),
    "success": pa.bool_(), "t_ns": pa.int64(), "kind": pa.string(), "reason": pa.string(), "joint": pa.string(),
    "asked": pa.float64(), "sent": pa.float64(), "category": pa.int64(), "policy_version": pa.string(),
    "calibration_version": pa.string(), "datum_version": pa.string(), "context_version": pa.string(),
    "site": pa.string(), "cell_id": pa.string(),
}
_TIME_KEY = {"cycles": "t_start_ns", "events": "t_ns"}
_STAMPS = ("policy_version", "calibration_version", "datum_version", "context_version", "site", "cell_id")
# the columns every row of a table has (cycle_row, event_row); cycles add one float64 column per feature
COLUMNS = {"cycles": ("cycle", "phase", "t_start_ns", "t_end_ns", "success", *_STAMPS),
           "events": ("cycle", "t_ns", "kind", "reason", "joint", "asked", "sent", "category", *_STAMPS)}


def default_opener(path: Path) -> BinaryIO:
    """A new file at ``path``; FileExistsError if anything is there: a record or an index part is never truncated
    in place (``wb`` on a live run's record emptied it under its writer)."""
    return open(path, "xb")


def clear_index(folder: Path) -> None:
    """Remove the Parquet parts an index writer made under ``folder`` and the folders they leave empty.

    Never a recursive delete: a file that is not an index part (a technician's notes, another
    tool's output) stays where it is, and so do the folders holding it.
    """
    folder = Path(folder)
    for table in TABLES:
        for part in (folder / table).glob(PART_GLOB):
            part.unlink()
        for day in (folder / table).glob("day=*"):
            if day.is_dir() and not any(day.iterdir()):
                day.rmdir()
        if (folder / table).is_dir() and not any((folder / table).iterdir()):
            (folder / table).rmdir()


class IndexWriter:
    """Buffers rows and writes them as day-partitioned Parquet parts (every ``part_rows`` rows, each day, at close)."""

    def __init__(self, folder: Path, epoch_wall_ns: int, part_rows: int = 5000,
                 opener: Callable[[Path], BinaryIO] = default_opener, record_id: str | None = None):
        self.folder = Path(folder)
        self.epoch_wall_ns = epoch_wall_ns
        self.record_id = record_id
        self.part_rows = part_rows
        self._opener = opener
        self._rows: dict[str, list[dict]] = {t: [] for t in TABLES}
        self._day: dict[str, str | None] = {t: None for t in TABLES}
        self._parts = {t: 0 for t in TABLES}

    def day_of(self, t_ns: int) -> str:
        return utc_day(self.epoch_wall_ns + t_ns).isoformat()

    def add(self, table: str, row: dict) -> None:
        """Append a row (time-ordered); raises OSError if a part cannot be written."""
        day = self.day_of(row[_TIME_KEY[table]])
        if self._day[table] not in (None, day) or len(self._rows[table]) >= self.part_rows:
            self._write(table)
        self._day[table] = day
        self._rows[table].append(row)

    def flush(self) -> None:
        """Write the rows still buffered. A table that had none at all gets one part of its columns and no rows, dated
        the run's start: an index without parts reads as none, and `record recover` of a run killed before its first
        cycle ended, with no event, wrote one that `record query` refused, pointing back at `record recover`."""
        for table in TABLES:
            self._write(table, empty=not self._parts[table])

    def _write(self, table: str, empty: bool = False) -> None:
        rows = self._rows[table]
        if not rows and not empty:
            return
        folder = self.folder / table / f"day={self._day[table] or self.day_of(0)}"
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"part-{self._parts[table]:08d}.parquet"
        part = rows_to_table(rows) if rows else _fixed(table).empty_table()
        if self.record_id:
            part = part.replace_schema_metadata({RECORD_ID_KEY: self.record_id.encode()})
        with self._opener(path) as f:
            pq.write_table(part, f, compression="zstd")
        self._parts[table] += 1
        self._rows[table] = []


def cycle_row(cycle: int, phase: str, t_start_ns: int, t_end_ns: int, success: bool, versions: dict,
              features: dict) -> dict:
    """One row of ``cycles``: identity, timing, outcome, context versions and site / cell id, then the features.

    A feature that repeats an identity column (``cycle``, ``success``) is left out: the column has it.
    """
    base = {"cycle": cycle, "phase": phase, "t_start_ns": t_start_ns, "t_end_ns": t_end_ns, "success": success}
    return {**base, **versions, **{k: (v if v is not None and math.isfinite(v) else None)
                                   for k, v in features.items() if k not in base}}


def event_row(event: dict, cycle: int | None, versions: dict) -> dict:
    """One row of ``events`` from an event's recorded fields."""
    keys = ("t_ns", "kind", "reason", "joint", "asked", "sent", "category")
    return {"cycle": cycle, **{k: event.get(k) for k in keys}, **versions}


def rows_to_table(rows: list[dict]) -> pa.Table:
    """Columns are the union of the rows' keys; anything not a known column is a float64 feature."""
    names = list(dict.fromkeys(k for row in rows for k in row))
    arrays = [pa.array([row.get(name) for row in rows], type=_BASE_TYPES.get(name, pa.float64())) for name in names]
    return pa.Table.from_arrays(arrays, names=names)


def indexed_run(schema: pa.Schema) -> str | None:
    """The record id an index part names (None: written before parts named one, or by another tool)."""
    value = (schema.metadata or {}).get(RECORD_ID_KEY)
    return value.decode(errors="replace") if value else None


def foreign_run(schema: pa.Schema, record_id: str | None) -> str | None:
    """The other run an index part names, when it names one and it is not ``record_id`` (a copied index)."""
    run = indexed_run(schema) if record_id else None
    return run if run not in (None, record_id) else None


def connect(folder: Path, con: duckdb.DuckDBPyConnection | None = None,
            record_id: str | None = None) -> duckdb.DuckDBPyConnection:
    """Views ``cycles`` and ``events`` over the index in ``folder`` on ``con`` (a new in-memory DuckDB if None).

    pyarrow reads the parts, each by its literal path: DuckDB's ``read_parquet`` expands ``*``, ``?`` and
    ``[...]`` in a file name, so a record under ``runs/run*`` would also read ``runs/runX``'s index, and its
    hive partitioning takes a ``key=value`` folder anywhere in the path for a column. A table without parts
    is empty but has its columns (and ``day``), so a query over it answers with no rows. pyarrow takes paths as
    UTF-8 text only: a folder whose name is not is refused in one line. ``record_id``: the run the index must be
    of; a part that names another run is refused.
    """
    folder = Path(folder)
    try:
        str(folder.absolute()).encode()
    except UnicodeEncodeError:
        raise RecordError(f"{folder}: the index cannot be read under a name that is not UTF-8 (pyarrow opens UTF-8 "
                          f"paths only); rename the folder, or link to it under a UTF-8 name") from None
    found = False
    views = {}
    for table in TABLES:
        parts = sorted((folder / table).glob("day=*/*.parquet"))
        found = found or bool(parts)
        views[table] = _parts(folder / table, table, parts, record_id) if parts else _empty(table)
    if not found:
        raise RecordError(f"{folder}: no index (no Parquet parts under cycles/ or events/); pass a run folder "
                          f"holding index/, or `cellguard record recover` rebuilds it from the record")
    con = duckdb.connect() if con is None else con
    for table, view in views.items():
        con.register(table, view)
    return con


def _parts(folder: Path, table: str, parts: list[Path], record_id: str | None) -> ds.Dataset:
    """The parts of one table as one dataset: the table's columns, then the others by name over all parts (a
    feature added later is null before; so is a version column a part has none of, as a record recovered
    without its context), then ``day`` from the folder names (a DATE when each is a date, as the writer names them)."""
    days = [p.parent.name.removeprefix("day=") for p in parts]
    day = pa.date32() if all(_is_date(d) for d in days) else pa.string()
    schemas = [_fixed(table)]
    for part in parts:
        try:
            schemas.append(pq.read_schema(part))
        except (OSError, pa.ArrowException) as exc:
            raise RecordError(f"{part}: the index part cannot be read ({first_line(exc)}); "
                              f"`cellguard record recover` rebuilds the index from the record") from None
        other = foreign_run(schemas[-1], record_id)
        if other is not None:
            raise RecordError(f"{part}: indexes run {other}, not this record's {record_id} (an "
                              f"index copied from another run); `cellguard record recover` rebuilds the index "
                              f"from the record")
    try:
        schema = pa.unify_schemas(schemas, promote_options="permissive").append(pa.field("day", day))
        return ds.dataset([str(p.absolute()) for p in parts], schema=schema, format="parquet",
                          filesystem=pafs.LocalFileSystem(), partition_base_dir=str(folder.absolute()),
                          partitioning=ds.HivePartitioning(pa.schema([("day", day)]), segment_encoding="none"))
    except pa.ArrowException as exc:
        raise RecordError(f"{folder}: the index parts do not make one table ({first_line(exc)}); "
                          f"`cellguard record recover` rebuilds the index from the record") from None


def _fixed(table: str) -> pa.Schema:
    return pa.schema([(name, _BASE_TYPES[name]) for name in COLUMNS[table]])


def _empty(table: str) -> pa.Table:
    return _fixed(table).append(pa.field("day", pa.date32())).empty_table()


def _is_date(text: str) -> bool:
    try:
        return bool(re.fullmatch(r"\d{4}-\d{2}-\d{2}", text)) and bool(dt.date.fromisoformat(text))
    except ValueError:
        return False


def first_line(exc: BaseException) -> str:
    """An exception's first line of text (or its type's name): one error line, never a wall of text."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def cycles_above_baseline(folder: Path, feature: str, quantile: float = 0.99) -> list[dict]:
    """Every cycle whose ``feature`` exceeds the acceptance baseline's ``quantile`` (time order)."""
    if not 0.0 < quantile < 1.0:
        raise RecordError(f"quantile: {quantile} is outside (0, 1)")
    con = connect(folder)
    column = '"' + feature.replace('"', '""') + '"'
    try:
        result = con.execute(
            f"SELECT cycle, t_start_ns, {column} AS value, context_version FROM cycles "
            f"WHERE {column} > (SELECT quantile_cont({column}, ?) FROM cycles WHERE phase = 'acceptance') "
            f"ORDER BY t_start_ns", [quantile])
    except duckdb.BinderException:
        raise RecordError(f"feature: {feature!r} is not a column of the cycle index") from None
    names = [d[0] for d in result.description]
    return [dict(zip(names, row)) for row in result.fetchall()]
