"""The Parquet lake: signatures (and their effect sizes) partitioned by tenant and date.

``LAKE/tenant=T/signatures/date=YYYY-MM-DD/<name>.parquet`` and the same under ``effects/``.
One folder per tenant (created owner-only, 0700), so the lake is fenced the way the store is:
the operator grants each tenant its own folder (file system or object-store prefix rights) and
the engines read a tenant's own rows from that folder only (``rights.py``). Each batch is one
file per partition, named by the batch's content hash and written beside its target then
renamed, holding only the signatures the partition's other files do not: re-sending a batch
replaces its file with the same rows, and a batch that repeats earlier signatures (a growing
folder pushed again) adds only its new ones. A signature id is the hash of every field, so two
rows with one id are the same row: the engines read each once even where a lake written before
this rule holds it twice (``lone_and_shared``). DuckDB (``duckdb_engine``) and Spark
(``spark_engine``) read the same files.
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
    """Write signature dicts (``Signature.to_dict()``) into their partitions as ``name``.parquet, each
    signature once: one already in another file of its partition is not written again. Returns the
    signatures written."""
    parts: dict[tuple[str, str], list[Mapping]] = defaultdict(list)
    for r in rows:
        parts[(r["created_date"], r["tenant_id"])].append(r)
    n = 0
    for (date, tenant), group in sorted(parts.items()):
        target = _file(lake, tenant, "signatures", date, name)
        there = _ids_beside(target)
        group = list({r["signature_id"]: r for r in group if r["signature_id"] not in there}.values())
        if not group:
            continue
        sig = {f.name: [_value(r, f.name) for r in group] for f in SIGNATURES}
        eff = [(r["tenant_id"], r["signature_id"], k, float(v)) for r in group for k, v in (r.get("effects") or {}).items()]
        _atomic(pa.Table.from_pydict(sig, schema=SIGNATURES), target)
        _atomic(pa.Table.from_pydict({c: [e[i] for e in eff] for i, c in enumerate(EFFECTS.names)}, schema=EFFECTS),
                _file(lake, tenant, "effects", date, name))
        n += len(group)
    return n


def check_lake(lake: Path) -> Path:
    """``lake`` if signatures can land there (a folder, or a path whose nearest existing parent is one),
    else OutputError: checked before anything is sent."""
    lake = Path(lake)
    probe = lake
    while not probe.exists() and probe.parent != probe:
        probe = probe.parent
    if not probe.is_dir():
        raise OutputError(f"--lake {lake}: {'not a folder' if probe == lake else f'{probe} is not a folder'}")
    return lake


def write_tables(lake: Path, signatures: pa.Table, effects: pa.Table, name: str) -> None:
    """Bulk form for large fleets: arrow tables already in the lake's schemas, one date and tenant."""
    date = signatures.column("created_date")[0].as_py().isoformat()
    tenant = signatures.column("tenant_id")[0].as_py()
    _atomic(signatures.cast(SIGNATURES), _file(lake, tenant, "signatures", date, name))
    _atomic(effects.cast(EFFECTS), _file(lake, tenant, "effects", date, name))


def tenant_dir(lake: Path, tenant: str) -> Path:
    """The tenant's own folder; the id is checked, so no glob or path can stand in for it."""
    if not isinstance(tenant, str) or not re.fullmatch(ID_PATTERN, tenant):
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


def paths(lake: Path, relation: str, tenant: str | None = None) -> list[str]:
    """``relation``'s files, listed (the lake's own path is taken literally, never as a pattern)."""
    root = tenant_dir(lake, tenant).name if tenant is not None else "tenant=*"
    return sorted(str(p) for p in Path(lake).glob(f"{root}/{relation}/date=*/*.parquet") if p.is_file())


def lone_and_shared(found: Iterable[str]) -> tuple[list[str], list[str]]:
    """(files alone in their partition folder, files that share one). A row can be repeated only
    within its partition (its signature's date and tenant are part of the id), in a folder holding
    more than one file: the engines read only those with ``DISTINCT``, the rest as they are."""
    by_folder: dict[str, list[str]] = defaultdict(list)
    for f in found:
        by_folder[os.path.dirname(f)].append(f)
    lone = [f for group in by_folder.values() if len(group) == 1 for f in group]
    return lone, [f for group in by_folder.values() if len(group) > 1 for f in group]


def has_data(lake: Path) -> bool:
    return bool(tenants(lake))


def _file(lake: Path, tenant: str, relation: str, date: str, name: str) -> Path:
    own = tenant_dir(lake, tenant)
    try:
        own.mkdir(mode=0o700, parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"lake folder {own}: cannot create ({exc.strerror or exc.__class__.__name__})") from None
    return own / relation / f"date={date}" / f"{name}.parquet"


def _ids_beside(target: Path) -> set[str]:
    """The signature ids in the other files of ``target``'s partition."""
    ids: set[str] = set()
    for other in sorted(target.parent.glob("*.parquet")) if target.parent.is_dir() else []:
        if other.name == target.name or not other.is_file():
            continue
        try:
            ids.update(pq.read_table(other, columns=["signature_id"]).column(0).to_pylist())
        except (OSError, pa.ArrowException) as exc:
            raise OutputError(f"lake file {other}: cannot read its signature ids ({exc.__class__.__name__})") from None
    return ids


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
