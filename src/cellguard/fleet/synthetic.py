"""A synthetic fleet at scale, resampled from real signatures: for benchmarks and engine tests.

Each row copies a seed signature's cause, robot model, cell type and effect sizes (times a
log-normal factor, so neighbours are near but not equal), under a random tenant, site, date and
policy/cellguard version. Vectorised: 10^6 signatures in a few seconds.
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Mapping, Sequence

import numpy as np
import pyarrow as pa

from cellguard.fleet.lake import EFFECTS, SIGNATURES, write_tables


def synthetic_fleet(seeds: Sequence[Mapping], n: int, tenants: int = 8, sites_per_tenant: int = 6, days: int = 30,
                    versions: int = 4, seed: int = 0, start: dt.date = dt.date(2026, 10, 1)) -> tuple[pa.Table, pa.Table]:
    """(signatures, effects) arrow tables in the lake's schemas, ``n`` signatures."""
    rng = np.random.default_rng(seed)
    pick = rng.integers(0, len(seeds), n)
    tenant = rng.integers(0, tenants, n)
    site = rng.integers(0, sites_per_tenant, n)
    day = rng.integers(0, days, n)
    version = np.minimum(day * versions // days + rng.integers(0, 2, n), versions - 1)  # rolled out over time
    ids = np.char.add("syn", np.char.zfill(np.arange(n).astype(str), 9))
    tid = np.char.add("t", tenant.astype(str))
    col = lambda key: np.array([s.get(key) for s in seeds], dtype=object)[pick]  # noqa: E731
    sig = {
        "signature_id": ids, "tenant_id": tid, "site_id": np.char.add(np.char.add(tid, "-s"), site.astype(str)),
        "created_date": np.datetime64(start) + day.astype("timedelta64[D]"), "cause": col("cause"),
        "confidence": col("confidence"), "robot_model": col("robot_model"), "cell_type": col("cell_type"),
        "onset_cycle": col("onset_cycle"), "detection_delay_cycles": col("detection_delay_cycles"),
        "policy_version": np.char.add("pv", version.astype(str)), "calibration_version": col("calibration_version"),
        "cellguard_version": np.char.add("0.1.", version.astype(str)), "recovery": np.full(n, None, object),
        "recovery_outcome": np.full(n, None, object), "schema_version": np.ones(n, np.int32),
    }
    signatures = pa.table({k: pa.array(v, type=SIGNATURES.field(k).type) for k, v in sig.items()})
    feats = [list((s.get("effects") or {}).items()) for s in seeds]
    counts = np.array([len(f) for f in feats])[pick]
    flat_names = [np.array([k for k, _ in f], dtype=object) for f in feats]
    flat_vals = [np.array([v for _, v in f], dtype=np.float64) for f in feats]
    rows = np.repeat(np.arange(n), counts)
    names = np.concatenate([flat_names[p] for p in pick]) if len(rows) else np.array([], object)
    vals = np.concatenate([flat_vals[p] for p in pick]) if len(rows) else np.array([])
    vals = vals * rng.lognormal(0.0, 0.25, len(vals))
    effects = pa.table({"tenant_id": pa.array(tid[rows]), "signature_id": pa.array(ids[rows]),
                        "feature": pa.array(names, pa.string()), "effect": pa.array(vals, pa.float64())})
    return signatures, effects.cast(EFFECTS)


def write_fleet(lake, signatures: pa.Table, effects: pa.Table, name: str = "synthetic") -> int:
    """Write the tables into the lake, one file per (date, tenant) partition; returns files written."""
    import pyarrow.compute as pc

    files = 0
    keys = pa.table({"d": signatures["created_date"], "t": signatures["tenant_id"]}).group_by(["d", "t"]).aggregate([])
    for d, t in zip(keys["d"].to_pylist(), keys["t"].to_pylist()):
        mask = pc.and_(pc.equal(signatures["created_date"], pa.scalar(d, pa.date32())), pc.equal(signatures["tenant_id"], t))
        part = signatures.filter(mask)
        emask = pc.is_in(effects["signature_id"], value_set=part["signature_id"])
        write_tables(lake, part, effects.filter(emask), name)
        files += 1
    return files


def rows_of(signatures: pa.Table, effects: pa.Table) -> list[dict]:
    """Signature dicts (``Signature.to_dict()`` shape) from the tables: for small fleets and tests."""
    by_id: dict[str, dict] = {}
    for e in effects.to_pylist():
        by_id.setdefault(e["signature_id"], {})[e["feature"]] = e["effect"]
    out = []
    for r in signatures.to_pylist():
        r["created_date"] = r["created_date"].isoformat()
        r["effects"] = by_id.get(r["signature_id"], {})
        out.append(r)
    return out
