"""Ticks as a long table (one row per tick and joint) for spreadsheets and other tools."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from cellguard.errors import RecordError
from cellguard.record.reader import Ticks
from cellguard.record.schemas import TICK_FIELDS


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
    """Write the table as csv or parquet; the number of rows written."""
    table = ticks_table(ticks)
    try:
        if fmt == "csv":
            pacsv.write_csv(table.set_column(2, "joint", table["joint"].cast(pa.string())), str(output))
        else:
            pq.write_table(table, str(output), compression="zstd")
    except OSError as exc:
        raise RecordError(f"-o {output}: cannot write ({exc})") from None
    return table.num_rows
