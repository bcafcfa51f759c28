"""Ticks as a long table (one row per tick and joint) for spreadsheets and other tools, and the check that
keeps every command's output off a record."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from cellguard.errors import RecordError
from cellguard.output import atomic_file
from cellguard.record.reader import Ticks, record_file
from cellguard.record.scan import MAGIC
from cellguard.record.writer import RECORD_FILE
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
    """Write the table as csv or parquet (beside the target, then renamed); the number of rows written.

    The caller checks ``output`` first with ``refuse_output``, before the ticks are read.
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


def refuse_output(output: Path, source: Path, to_folder: bool = False) -> None:
    """RecordError unless ``output`` may be written: nothing recorded is ever overwritten.

    Every command that writes (export, to-lerobot, recover, report) calls this before it reads
    anything. Refused, after following links: the record being read (``source``, a run folder or
    an .mcap file, whatever its bytes hold), a file that starts with the MCAP magic, and a run
    folder (one holding record.mcap) or anything in it, since its summary, index and baseline
    belong to the record. ``to_folder``: the output is a folder to fill, else a file.
    """
    try:
        target = Path(output).resolve()
        if target == record_file(source).resolve():
            raise RecordError(f"-o {output}: is the record being read; cellguard never overwrites a record; "
                              f"choose another path")
        run = next((d for d in (target, *target.parents) if (d / RECORD_FILE).exists()), None)
        if run is not None:
            where = "is a run folder" if run == target else f"is in the run folder {run}"
            raise RecordError(f"-o {output}: {where}, which holds a record; cellguard never overwrites a record "
                              f"or its run folder; choose a path outside it")
        if target.is_file():
            with open(target, "rb") as f:
                if f.read(len(MAGIC)) == MAGIC:
                    raise RecordError(f"-o {output}: is a record; cellguard never overwrites a record; "
                                      f"choose another path")
    except (OSError, RuntimeError) as exc:  # RuntimeError: a symlink loop
        raise RecordError(f"-o {output}: cannot be checked ({getattr(exc, 'strerror', None) or exc})") from None
    if to_folder and target.exists() and not target.is_dir():
        raise RecordError(f"-o {output}: is a file; give a new folder")
    if not to_folder and target.is_dir():
        raise RecordError(f"-o {output}: is a folder; name a file to write")
