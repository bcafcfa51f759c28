"""The index for long histories: one Parquet row per cycle and per event, partitioned by day.

The MCAP file is the record; the index is derived from it (``record recover`` rebuilds it) and
exists so that a question over a month of cycles reads one row per cycle instead of rescanning
ticks. Rows arrive in time order and are written in parts (``index/cycles/day=YYYY-MM-DD/
part-NNNNNNNN.parquet``), so files stay time-sorted and a query can skip whole days. Each row is
stamped with the context versions (policy, calibration, datum) it was recorded under.
"""

from __future__ import annotations

import datetime as dt
import math
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

import duckdb
import pyarrow as pa
import pyarrow.parquet as pq

from cellguard.errors import RecordError

TABLES = ("cycles", "events")
_BASE_TYPES = {
    "cycle": pa.int64(), "phase": pa.string(), "t_start_ns": pa.int64(), "t_end_ns": pa.int64(),
    "success": pa.bool_(), "t_ns": pa.int64(), "kind": pa.string(), "reason": pa.string(), "joint": pa.string(),
    "asked": pa.float64(), "sent": pa.float64(), "category": pa.int64(), "policy_version": pa.string(),
    "calibration_version": pa.string(), "datum_version": pa.string(), "context_version": pa.string(),
    "site": pa.string(), "cell_id": pa.string(),
}
_TIME_KEY = {"cycles": "t_start_ns", "events": "t_ns"}


def default_opener(path: Path) -> BinaryIO:
    return open(path, "wb")


def clear_index(folder: Path) -> None:
    """Remove the Parquet parts an index writer made under ``folder`` and the folders they leave empty.

    Never a recursive delete: a file that is not an index part (a technician's notes, another
    tool's output) stays where it is, and so do the folders holding it.
    """
    folder = Path(folder)
    for table in TABLES:
        for part in (folder / table).glob("day=*/part-*.parquet"):
            part.unlink()
        for day in (folder / table).glob("day=*"):
            if day.is_dir() and not any(day.iterdir()):
                day.rmdir()
        if (folder / table).is_dir() and not any((folder / table).iterdir()):
            (folder / table).rmdir()


class IndexWriter:
    """Buffers rows and writes them as day-partitioned Parquet parts (every ``part_rows`` rows, each day, at close)."""

    def __init__(self, folder: Path, epoch_wall_ns: int, part_rows: int = 5000,
                 opener: Callable[[Path], BinaryIO] = default_opener):
        self.folder = Path(folder)
        self.epoch_wall_ns = epoch_wall_ns
        self.part_rows = part_rows
        self._opener = opener
        self._rows: dict[str, list[dict]] = {t: [] for t in TABLES}
        self._day: dict[str, str | None] = {t: None for t in TABLES}
        self._parts = {t: 0 for t in TABLES}

    def day_of(self, t_ns: int) -> str:
        return dt.datetime.fromtimestamp((self.epoch_wall_ns + t_ns) * 1e-9, dt.timezone.utc).date().isoformat()

    def add(self, table: str, row: dict) -> None:
        """Append a row (time-ordered); raises OSError if a part cannot be written."""
        day = self.day_of(row[_TIME_KEY[table]])
        if self._day[table] not in (None, day) or len(self._rows[table]) >= self.part_rows:
            self._write(table)
        self._day[table] = day
        self._rows[table].append(row)

    def flush(self) -> None:
        for table in TABLES:
            self._write(table)

    def _write(self, table: str) -> None:
        rows = self._rows[table]
        if not rows:
            return
        folder = self.folder / table / f"day={self._day[table]}"
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"part-{self._parts[table]:08d}.parquet"
        with self._opener(path) as f:
            pq.write_table(rows_to_table(rows), f, compression="zstd")
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


def connect(folder: Path) -> duckdb.DuckDBPyConnection:
    """An in-memory DuckDB with views ``cycles`` and ``events`` over the index in ``folder``."""
    folder = Path(folder)
    con = duckdb.connect()
    found = False
    for table in TABLES:
        parts = sorted((folder / table).glob("day=*/*.parquet"))
        if parts:
            found = True
            # the files by name, not a glob: a folder named like a pattern ("[1]*?") is not expanded by DuckDB
            files = ", ".join("'" + str(p).replace("'", "''") + "'" for p in parts)
            con.execute(f"CREATE VIEW {table} AS SELECT * FROM read_parquet([{files}], hive_partitioning = true, "
                        f"union_by_name = true)")
        else:
            con.execute(f"CREATE VIEW {table} AS SELECT NULL::BIGINT AS {_TIME_KEY[table]} WHERE false")
    if not found:
        raise RecordError(f"{folder}: no index (no Parquet parts under cycles/ or events/); "
                          f"`cellguard record recover` rebuilds it from the record")
    return con


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
