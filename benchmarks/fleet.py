"""A simulated fleet on the real store and lake; prints one JSON document.

24 sites across 4 tenants with different data policies, built from real cellguard runs with
varied faults (``fleet_runs.py``, cached in out/fleet-runs), pushed to the PostgreSQL store that
``.ci/fleet.sh`` starts and landed in a Parquet lake. Reports: what each policy let through,
the k refusal, ``fleet similar`` on 5 held-out faults, DuckDB against Spark on every shared
query, and both on 10^6 synthetic signatures resampled from the real ones. Timings are ratios
to one ``mj_step`` of the arm cell measured in the same run; never asserted.

    .ci/fleet.sh && python benchmarks/fleet.py [--rows 1000000] [--no-spark]
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import pyarrow.parquet as pq

sys.path.insert(0, str(Path(__file__).parent))

from fleet_runs import DEFAULT_DIR, make_runs  # noqa: E402

from cellguard.fleet.from_record import site_signatures  # noqa: E402
from cellguard.fleet.policy import DataPolicy  # noqa: E402
from cellguard.fleet.push import push  # noqa: E402
from cellguard.fleet.queries import QUERIES  # noqa: E402
from cellguard.fleet.similar import similar  # noqa: E402
from cellguard.fleet.store import FleetStore, RefusedAggregate, TenantStore, ci_admin_dsn  # noqa: E402
from cellguard.fleet.synthetic import rows_of, synthetic_fleet, write_fleet  # noqa: E402

TENANTS = {  # tenant -> its data policy (sites s-<tenant>-<j>)
    "t-alpha": dict(export="signatures"),
    "t-beta": dict(export="signatures", withheld=("policy_version", "calibration_version")),
    "t-gamma": dict(export="aggregates_only", min_group_size=2),
    "t-delta": dict(export="nothing"),
}
SITES_PER_TENANT = 6
PROBE_QUERY = {"site": "s-new", "robot_model": "", "limit": 10}


def mj_step_s() -> float:
    """One mj_step of the arm cell [s] (median of 2000): the reference the timings are divided by."""
    import mujoco

    from cellguard.robot.registry import make_cell
    cell = make_cell("arm-pick-place")
    model, data = cell.model, cell.data
    times = []
    for _ in range(2000):
        t = time.perf_counter()
        mujoco.mj_step(model, data)
        times.append(time.perf_counter() - t)
    return sorted(times)[len(times) // 2]


def build_fleet(runs: dict, store: FleetStore, site_root: Path, lake: Path) -> dict:
    """Push every site's runs under its tenant's policy; what each policy let through."""
    pool = sorted(n for n in runs if n.startswith("pool"))
    per_run = {n: site_signatures(runs[n][0], DataPolicy("t-x", "s-x")) for n in pool}
    out = {}
    for tenant, pol in TENANTS.items():
        dsn = store.add_tenant(tenant)
        sent = withheld = 0
        for j in range(SITES_PER_TENANT):
            policy = DataPolicy(tenant, f"s-{tenant[2:]}-{j}", **pol)
            mine = [replace(s, tenant_id=policy.tenant, site_id=policy.site)
                    for n in pool[2 * j:2 * j + 2] for s in per_run[n]]
            r = push(mine, policy, site_root / policy.site, TenantStore(dsn), lake)
            sent, withheld = sent + r.new_rows, withheld + r.batch.withheld_rows
        out[tenant] = {"policy": pol["export"], "sites": SITES_PER_TENANT, "rows_sent": sent,
                       "signatures_kept_at_site": withheld, "dsn": dsn}
    return out


def held_out(runs: dict, dsn: str) -> dict:
    """``fleet similar`` on each held-out fault as tenant t-alpha: is its true cause in the top 5?"""
    cases = []
    for name in sorted(n for n in runs if n.startswith("held")):
        folder, cause = runs[name]
        probes = site_signatures(folder, DataPolicy("t-alpha", "s-new"))
        if not probes:
            cases.append({"run": name, "cause": cause, "diagnosed": None, "top5": [], "hit": False})
            continue
        probe = max(probes, key=lambda s: s.confidence or 0.0)
        top = similar(TenantStore(dsn), probe, limit=5)
        cases.append({"run": name, "cause": cause, "diagnosed": probe.cause, "top5": [n.cause for n in top],
                      "similarity": [round(n.similarity, 3) for n in top], "hit": cause in [n.cause for n in top]})
    return {"hits": sum(c["hit"] for c in cases), "cases": len(cases), "detail": cases}


def compare_engines(lake: Path, probe: list, spark: bool, ref_s: float, repeat: int = 3) -> dict:
    """Every shared query on DuckDB and Spark: equal results?, time of each (best of ``repeat``)."""
    from cellguard.fleet.duckdb_engine import DuckDBEngine
    engines = [DuckDBEngine(lake)]
    start = {}
    if spark:
        from cellguard.fleet.spark_engine import SparkEngine
        t = time.perf_counter()
        engines.append(SparkEngine(lake))
        start["spark_session_s"] = time.perf_counter() - t
    out = {"queries": {}, **start}
    for name in QUERIES:
        params = {"k": 2} if name != "similar" else PROBE_QUERY
        res = {}
        for eng in engines:
            best = float("inf")
            for _ in range(repeat):
                t = time.perf_counter()
                rows = eng.run(name, params, probe)
                best = min(best, time.perf_counter() - t)
            res[eng.name] = (rows, best)
        row = {"rows": len(res["duckdb"][0])}
        for eng, (_, s) in res.items():
            row[f"{eng}_s"] = round(s, 4)
            row[f"{eng}_in_mj_steps"] = round(s / ref_s)
        if "spark" in res:
            row["equal"] = equal(res["duckdb"][0], res["spark"][0])
        out["queries"][name] = row
    for eng in engines:
        eng.close()
    return out


def equal(a: list[dict], b: list[dict]) -> bool:
    """Same rows in the same order; floats equal to 1e-9."""
    if len(a) != len(b):
        return False
    for x, y in zip(a, b):
        if x.keys() != y.keys():
            return False
        for k in x:
            if isinstance(x[k], float) or isinstance(y[k], float):
                if x[k] is None or y[k] is None or abs(x[k] - y[k]) > 1e-9 * max(1.0, abs(x[k])):
                    return False
            elif x[k] != y[k]:
                return False
    return True


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=Path, default=DEFAULT_DIR)
    ap.add_argument("--rows", type=int, default=1_000_000)
    ap.add_argument("--no-spark", action="store_true")
    args = ap.parse_args()
    t0 = time.perf_counter()
    admin = ci_admin_dsn()
    if admin is None:
        sys.exit("no fleet store server: run .ci/fleet.sh first")
    runs = make_runs(args.runs)
    t_runs = time.perf_counter() - t0
    ref = mj_step_s()
    work = Path(tempfile.mkdtemp(prefix="cellguard-fleet-"))
    try:
        store = FleetStore(admin, "cgbench_fleet")
        store.install(reset=True)
        lake = work / "lake"
        tenants = build_fleet(runs, store, work / "sites", lake)
        alpha = tenants["t-alpha"].pop("dsn")
        for t in tenants.values():
            t.pop("dsn", None)
        try:
            TenantStore(alpha).run("frequency")
            refusal = None
        except RefusedAggregate as exc:
            refusal = str(exc)
        store.set_min_customers(2)
        fleet_freq = TenantStore(alpha).run("frequency", {"k": 2})
        similar_eval = held_out(runs, alpha)
        probe = sorted(site_signatures(runs["held-00-fixture_shift"][0], DataPolicy("t-x", "s-x"))[0].effects.items())
        small = compare_engines(lake, probe, not args.no_spark, ref, repeat=1)

        seeds = rows_of(pq.read_table(lake / "signatures"), pq.read_table(lake / "effects"))
        t = time.perf_counter()
        sig, eff = synthetic_fleet(seeds, args.rows, tenants=8, days=30)
        big = work / "big"
        files = write_fleet(big, sig, eff)
        t_write = time.perf_counter() - t
        scale = compare_engines(big, probe, not args.no_spark, ref)
        print(json.dumps({
            "sites": sum(t["sites"] for t in tenants.values()), "tenants": tenants,
            "real_runs": len(runs), "runs_made_or_cached_s": round(t_runs, 1),
            "k_default_refusal": refusal, "fleet_frequency_k2": fleet_freq,
            "similar_held_out": similar_eval, "engines_on_fleet_lake": small,
            "scale": {"signatures": args.rows, "effect_rows": eff.num_rows, "files": files,
                      "synthesise_and_write_s": round(t_write, 1), **scale},
            "reference_mj_step_s": ref, "total_s": round(time.perf_counter() - t0, 1),
        }, indent=1, default=str))
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
