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
    order = np.lexsort((tenant, day))  # partition by partition: each is one slice (see write_fleet)
    pick, tenant, site, day = pick[order], tenant[order], site[order], day[order]
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
    all_names = np.array([k for f in feats for k, _ in f], dtype=object)
    all_vals = np.array([v for f in feats for _, v in f], dtype=np.float64)
    per_seed = np.array([len(f) for f in feats])
    counts = per_seed[pick]
    rows = np.repeat(np.arange(n), counts)
    first = np.repeat(np.cumsum(counts) - counts, counts)  # where each signature's effects begin
    idx = np.repeat((np.cumsum(per_seed) - per_seed)[pick], counts) + np.arange(len(rows)) - first
    names, vals = all_names[idx], all_vals[idx]
    vals = vals * rng.lognormal(0.0, 0.25, len(vals))
    effects = pa.table({"tenant_id": pa.array(tid[rows]), "signature_id": pa.array(ids[rows]),
                        "feature": pa.array(names, pa.string()), "effect": pa.array(vals, pa.float64())})
    return signatures, effects.cast(EFFECTS)


def write_fleet(lake, signatures: pa.Table, effects: pa.Table, name: str = "synthetic") -> int:
    """Write tables sorted by (date, tenant), effects in signature order (as ``synthetic_fleet``
    makes them) into the lake, one file per partition; returns the files written."""
    keys = np.char.add(np.asarray(signatures["created_date"].cast(pa.string())).astype(str),
                       np.asarray(signatures["tenant_id"]).astype(str))
    starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
    ends = np.r_[starts[1:], len(keys)]
    eff_ids = np.asarray(effects["signature_id"]).astype(str)
    sig_ids = np.asarray(signatures["signature_id"]).astype(str)
    for a, b in zip(starts, ends):
        lo = np.searchsorted(eff_ids, sig_ids[a], "left")
        hi = np.searchsorted(eff_ids, sig_ids[b - 1], "right")
        write_tables(lake, signatures.slice(a, b - a), effects.slice(lo, hi - lo), name)
    return len(starts)


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
