"""Ticks as a long table (one row per tick and joint) for spreadsheets and other tools."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from cellguard.errors import RecordError
from cellguard.output import atomic_file
from cellguard.record.reader import Ticks
from cellguard.record.schemas import TICK_FIELDS

SUFFIXES = {"csv": (".csv",), "parquet": (".parquet", ".pq")}  # the formats written, and the file names that say them


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


def write_ticks(ticks: Ticks, output: Path, fmt: str) -> int:
    """Write the table as csv or parquet (beside the target, then renamed); the number of rows written.

    The caller checks ``output`` first with ``refuse_output`` and ``check_format``, before the ticks are read.
    """
    output = Path(output)
    table = ticks_table(ticks)
    try:
        with atomic_file(output, "-o") as f:
            if fmt == "csv":
                pacsv.write_csv(table.set_column(2, "joint", table["joint"].cast(pa.string())), f)
            else:
                pq.write_table(table, f, compression="zstd")
    except pa.ArrowException as exc:
        raise RecordError(f"-o {output}: cannot write ({exc})") from None
    return table.num_rows
