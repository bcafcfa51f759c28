"""The Parquet lake: signatures (and their effect sizes) partitioned by tenant and date.

``LAKE/tenant=T/signatures/date=YYYY-MM-DD/<name>.parquet`` and the same under ``effects/``.
One folder per tenant (created owner-only, 0700), so the lake is fenced the way the store is:
the operator grants each tenant its own folder (file system or object-store prefix rights) and
the engines read a tenant's own rows from that folder only (``rights.py``). Each batch is one
file per partition, named by the batch's content hash and written beside its target then
renamed: re-sending a batch replaces its file with the same rows, never duplicates. DuckDB
(``duckdb_engine``) and Spark (``spark_engine``) read the same files.
"""

from __future__ import annotations

import datetime as dt
import os
import re
from collections import defaultdict
from collections.abc import Iterable, Mapping
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from cellguard.errors import ConfigError, OutputError
from cellguard.fleet.signature import ID_PATTERN

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
        _atomic(pa.Table.from_pydict(sig, schema=SIGNATURES), _file(lake, tenant, "signatures", date, name))
        _atomic(pa.Table.from_pydict({c: [e[i] for e in eff] for i, c in enumerate(EFFECTS.names)}, schema=EFFECTS),
                _file(lake, tenant, "effects", date, name))
        n += len(group)
    return n


def write_tables(lake: Path, signatures: pa.Table, effects: pa.Table, name: str) -> None:
    """Bulk form for large fleets: arrow tables already in the lake's schemas, one date and tenant."""
    date = signatures.column("created_date")[0].as_py().isoformat()
    tenant = signatures.column("tenant_id")[0].as_py()
    _atomic(signatures.cast(SIGNATURES), _file(lake, tenant, "signatures", date, name))
    _atomic(effects.cast(EFFECTS), _file(lake, tenant, "effects", date, name))


def tenant_dir(lake: Path, tenant: str) -> Path:
    """The tenant's own folder; the id is checked, so no glob or path can stand in for it."""
    if not isinstance(tenant, str) or not re.match(ID_PATTERN, tenant):
        raise ConfigError(f"tenant: expected an opaque id matching {ID_PATTERN}, got {tenant!r}")
    return Path(lake) / f"tenant={tenant}"


def tenants(lake: Path) -> list[str]:
    """The tenants with signatures in the lake (from the folder names: no file is opened)."""
    return sorted(p.name.removeprefix("tenant=") for p in Path(lake).glob("tenant=*")
                  if any((p / "signatures").glob("date=*/*.parquet")))


def files(lake: Path, relation: str, tenant: str | None = None) -> str:
    """The glob of ``relation``'s files: one tenant's, or (``None``) every tenant's."""
    root = tenant_dir(lake, tenant) if tenant is not None else Path(lake) / "tenant=*"
    return str(root / relation / "date=*" / "*.parquet")


def has_data(lake: Path) -> bool:
    return bool(tenants(lake))


def _file(lake: Path, tenant: str, relation: str, date: str, name: str) -> Path:
    own = tenant_dir(lake, tenant)
    try:
        own.mkdir(mode=0o700, parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"lake folder {own}: cannot create ({exc.strerror or exc.__class__.__name__})") from None
    return own / relation / f"date={date}" / f"{name}.parquet"


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
