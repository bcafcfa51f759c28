"""The Parquet lake: signatures (and their effect sizes) partitioned by date and tenant.

``LAKE/signatures/date=YYYY-MM-DD/tenant=T/<name>.parquet`` and the same under ``effects/``.
Each batch is one file per partition, named by the batch's content hash and written beside its
target then renamed: re-sending a batch replaces its file with the same rows, never duplicates.
DuckDB (``duckdb_engine``) and Spark (``spark_engine``) read the same files.
"""

from __future__ import annotations

import datetime as dt
import os
from collections import defaultdict
from collections.abc import Iterable, Mapping
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from cellguard.errors import OutputError

SIGNATURES = pa.schema([
    ("signature_id", pa.string()), ("tenant_id", pa.string()), ("site_id", pa.string()),
    ("created_date", pa.date32()), ("cause", pa.string()), ("confidence", pa.float64()),
    ("robot_model", pa.string()), ("cell_type", pa.string()), ("onset_cycle", pa.int64()),
    ("detection_delay_cycles", pa.int64()), ("policy_version", pa.string()), ("calibration_version", pa.string()),
    ("cellguard_version", pa.string()), ("recovery", pa.string()), ("recovery_outcome", pa.string()),
    ("schema_version", pa.int32()),
])
EFFECTS = pa.schema([("tenant_id", pa.string()), ("signature_id", pa.string()), ("feature", pa.string()),
                     ("effect", pa.float64())])


def write_signatures(lake: Path, rows: Iterable[Mapping], name: str) -> int:
    """Write signature dicts (``Signature.to_dict()``) into their partitions as ``name``.parquet."""
    parts: dict[tuple[str, str], list[Mapping]] = defaultdict(list)
    for r in rows:
        parts[(r["created_date"], r["tenant_id"])].append(r)
    n = 0
    for (date, tenant), group in sorted(parts.items()):
        sig = {f.name: [_value(r, f.name) for r in group] for f in SIGNATURES}
        eff = [(r["tenant_id"], r["signature_id"], k, float(v)) for r in group for k, v in (r.get("effects") or {}).items()]
        where = f"date={date}/tenant={tenant}/{name}.parquet"
        _atomic(pa.Table.from_pydict(sig, schema=SIGNATURES), Path(lake) / "signatures" / where)
        _atomic(pa.Table.from_pydict({c: [e[i] for e in eff] for i, c in enumerate(EFFECTS.names)}, schema=EFFECTS),
                Path(lake) / "effects" / where)
        n += len(group)
    return n


def write_tables(lake: Path, signatures: pa.Table, effects: pa.Table, name: str) -> None:
    """Bulk form for large fleets: arrow tables already in the lake's schemas, one date and tenant."""
    date = signatures.column("created_date")[0].as_py().isoformat()
    tenant = signatures.column("tenant_id")[0].as_py()
    where = f"date={date}/tenant={tenant}/{name}.parquet"
    _atomic(signatures.cast(SIGNATURES), Path(lake) / "signatures" / where)
    _atomic(effects.cast(EFFECTS), Path(lake) / "effects" / where)


def has_data(lake: Path) -> bool:
    return any((Path(lake) / "signatures").glob("*/*/*.parquet"))


def _value(row: Mapping, name: str):
    v = row.get(name)
    return dt.date.fromisoformat(v) if name == "created_date" and isinstance(v, str) else v


def _atomic(table: pa.Table, path: Path) -> None:
    tmp = path.with_name(path.name + ".tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(table, tmp, compression="zstd")
        os.replace(tmp, path)
    except OSError as exc:
        raise OutputError(f"lake file {path}: cannot write ({exc.strerror or exc.__class__.__name__})") from None
