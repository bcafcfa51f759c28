"""A simulated fleet on the real store and lake; prints one JSON document.

24 sites across 4 tenants with different data policies, built from 54 real cellguard runs with
varied faults (``fleet_runs.py``, cached in out/fleet-runs; ``--runs`` elsewhere makes them
afresh), pushed to the PostgreSQL store that ``.ci/fleet.sh`` starts and landed in a Parquet
lake. Reports: what each policy let through and what the store holds, the k refusal, ``fleet
similar`` on 5 held-out faults, the lake as one tenant sees it, and DuckDB against Spark on
every shared query on 10^6 signatures resampled from the real ones. Each phase's wall and CPU
seconds (Spark's JVM included) go to stderr as it ends; query timings are also given as
multiples of one ``mj_step`` of the arm cell measured in the same run; never asserted.

The store is this run's own (``cg<run>_bench``, tagged as a benchmark's: ``cellguard.fleet.run_stores``, as the tests'
stores) and dropped at its end: two benchmarks, or a benchmark and the tests, on one server leave each other's store
alone, and a killed run's is dropped by the next benchmark or test session to use the server. A server that cannot
be reached, before or during the run, ends it with one line (exit 1); its work folder is removed and its store
dropped on an error, Ctrl-C, SIGTERM or SIGHUP (exit 128 + the signal), not on SIGKILL.

    .ci/fleet.sh && python benchmarks/fleet.py [--runs DIR] [--rows 1000000] [--no-spark]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

import pyarrow.parquet as pq

sys.path.insert(0, str(Path(__file__).parent))

from fleet_runs import DEFAULT_DIR, TENANTS, make_fleet  # noqa: E402

from cellguard.ending import ended_by_signals  # noqa: E402
from cellguard.fleet.policy import DataPolicy  # noqa: E402
from cellguard.fleet.push import push  # noqa: E402
from cellguard.fleet.queries import QUERIES  # noqa: E402
from cellguard.fleet.run_stores import RunStores  # noqa: E402
from cellguard.fleet.similar import similar  # noqa: E402
from cellguard.fleet.store import (FleetStore, RefusedAggregate, StoreError, StoreUnavailable,  # noqa: E402
                                   TenantStore, ci_admin_dsn, connect)
from cellguard.fleet.synthetic import rows_of, synthetic_fleet, write_fleet  # noqa: E402

POLICIES = {  # tenant -> its data policy (sites s-<tenant>-<j>)
    "t-alpha": dict(export="signatures"),
    "t-beta": dict(export="signatures", withheld=("policy_version", "calibration_version")),
    "t-gamma": dict(export="aggregates_only", min_group_size=2),
    "t-delta": dict(export="nothing"),
}
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


def build_fleet(runs: dict, store: FleetStore, stores: RunStores, site_root: Path, lake: Path) -> dict:
    """Push every site's signatures under its tenant's policy (each tenant's role tagged as ``stores``'); what each
    policy let through."""
    by_site: dict[tuple[str, str], list] = {}
    for run, sigs in runs["site"].values():
        by_site.setdefault((run.tenant, run.site), []).extend(sigs)
    out = {}
    for tenant in TENANTS:
        dsn = store.add_tenant(tenant)
        stores.tag_stores()  # its role too: a run killed from here on leaves nothing untagged
        sites = sorted(s for t, s in by_site if t == tenant)
        found = sent = withheld = 0
        for site in sites:
            policy = DataPolicy(tenant, site, **POLICIES[tenant])
            r = push(by_site[(tenant, site)], policy, site_root / site, TenantStore(dsn), lake)
            found += len(by_site[(tenant, site)])
            sent, withheld = sent + r.new_rows, withheld + r.batch.withheld_rows
        out[tenant] = {"policy": POLICIES[tenant]["export"], "sites": len(sites), "signatures_found": found,
                       "rows_sent": sent, "signatures_kept_at_site": withheld, "dsn": dsn}
    return out


def store_contents(store: FleetStore) -> dict:
    """What the store holds per tenant, read as its superuser: rows per table, and beta's rows
    that still carry a field its policy withholds (should be none)."""
    with store.admin() as con:
        per = {t: {tab: con.execute(f"SELECT count(*) FROM fleet.{tab} WHERE tenant_id = %s", (t,)).fetchone()[0]
                   for tab in ("signatures", "effects", "aggregates")} for t in TENANTS}
        leaked = con.execute("SELECT count(*) FROM fleet.signatures WHERE tenant_id = 't-beta' AND "
                             "(policy_version IS NOT NULL OR calibration_version IS NOT NULL)").fetchone()[0]
    return {"rows_per_tenant": per, "t_beta_rows_with_a_withheld_field": leaked}


def held_out(runs: dict, dsn: str) -> dict:
    """``fleet similar`` on each held-out fault as tenant t-alpha: is its true cause in the top 5?"""
    cases = []
    for name, (run, probes) in sorted(runs["held"].items()):
        if not probes:
            cases.append({"run": name, "cause": run.cause, "diagnosed": None, "top5": [], "hit": False})
            continue
        probe = max(probes, key=lambda s: s.confidence or 0.0)
        top = similar(TenantStore(dsn), probe, limit=5)
        cases.append({"run": name, "cause": run.cause, "diagnosed": probe.cause, "top5": [n.cause for n in top],
                      "similarity": [round(n.similarity, 3) for n in top],
                      "hit": run.cause in [n.cause for n in top]})
    return {"hits": sum(c["hit"] for c in cases), "cases": len(cases), "detail": cases}


def compare_engines(engines: list, probe: list, ref_s: float, repeat: dict) -> dict:
    """Every shared query on each engine (as the operator): equal results?, time of each (best
    of ``repeat[engine]`` runs)."""
    out = {}
    for name in QUERIES:
        params = {"k": 2} if name != "similar" else PROBE_QUERY
        res = {}
        for eng in engines:
            best = float("inf")
            for _ in range(repeat.get(eng.name, 1)):
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
        out[name] = row
    return out


def engines_on(lake: Path, spark: bool) -> tuple[list, float | None]:
    """DuckDB, and Spark when asked, on ``lake`` as the operator; the seconds Spark took to start
    (a session already running is reused: None)."""
    from cellguard.fleet.duckdb_engine import DuckDBEngine
    engines = [DuckDBEngine(lake)]
    started = None
    if spark:
        from pyspark.sql import SparkSession

        from cellguard.fleet.spark_engine import SparkEngine
        fresh = SparkSession.getActiveSession() is None
        t = time.perf_counter()
        engines.append(SparkEngine(lake))
        started = time.perf_counter() - t if fresh else None
    return engines, started


def fenced_lake(lake: Path, tenant: str) -> dict:
    """The lake as one tenant sees it: own rows only, the fleet's only over k customers."""
    from cellguard.fleet.duckdb_engine import DuckDBEngine
    eng = DuckDBEngine(lake, tenant)
    own = eng.run("frequency", scope="own")
    try:
        eng.run("frequency", {"k": 2})
        refusal = None
    except RefusedAggregate as exc:
        refusal = str(exc)
    mine = {r["site_id"] for r in eng.run("similar", {"site": "s-new", "limit": 1000},
                                          [("fixture_seen_x_mm", 1.0)])}
    eng.close()
    return {"tenant": tenant, "own_signatures": sum(r["signatures"] for r in own),
            "similar_sites_all_own": all(s.startswith(f"s-{tenant[2:]}-") for s in mine),
            "cross_customer_k2_refused": refusal}


def cpu_s() -> float:
    """CPU seconds so far of this process, its finished workers and Spark's JVM."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime + (jvm_cpu_s() or 0.0)


def jvm_cpu_s() -> float | None:
    """CPU seconds of Spark's JVM (and the children it waited for) so far; None without Spark."""
    try:
        from pyspark import SparkContext
        pid = SparkContext._gateway.proc.pid
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (ImportError, AttributeError, OSError):
        return None
    return round(sum(int(x) for x in fields[11:15]) / os.sysconf("SC_CLK_TCK"), 1)  # utime stime cutime cstime


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
    ap.add_argument("--spark-on-fleet-lake", action="store_true",
                    help="also compare Spark on the 24-site lake (a minute more; Spark is compared at scale anyway)")
    args = ap.parse_args()
    t0, load0 = time.perf_counter(), os.getloadavg()
    phases: dict[str, dict] = {}
    last = [t0, cpu_s()]

    def lap(name: str) -> None:
        """Wall and CPU seconds (this process, its finished workers and Spark's JVM) since the last lap,
        also on stderr as it goes (a run cut short still says where its time went)."""
        now, cpu = time.perf_counter(), cpu_s()
        phases[name] = {"wall_s": round(now - last[0], 1), "cpu_s": round(cpu - last[1], 1),
                        "load_1min": round(os.getloadavg()[0], 1)}
        last[:] = [now, cpu]
        print(f"{name}: {json.dumps(phases[name])}", file=sys.stderr, flush=True)

    admin = ci_admin_dsn()
    if admin is None:
        sys.exit("no fleet store server: run .ci/fleet.sh first")
    try:
        connect(admin).close()  # before the runs are made: minutes, wasted on a server not there
        runs = make_fleet(args.runs)
        lap("runs_made_and_diagnosed")
        ref = mj_step_s()
        bench(args, admin, runs, ref, lap, phases, t0, load0)
    except StoreError as exc:  # a server gone meanwhile too: one line, the store dropped and the folder removed
        sys.exit(f"{exc}: run .ci/fleet.sh first" if isinstance(exc, StoreUnavailable) else str(exc))


def bench(args, admin: str, runs: dict, ref: float, lap, phases: dict, t0: float, load0: tuple) -> None:
    """The store's and the lake's phases, on this run's own store (dropped at the end, as its work folder is removed
    whatever ends the run); prints the JSON document."""
    stores = RunStores("benchmark", "cellguard fleet benchmark")
    work = Path(tempfile.mkdtemp(prefix="cellguard-fleet-"))
    try:
        stores.open(admin)  # this run's lock held to its end; killed runs' stores swept
        store = FleetStore(admin, stores.name("bench"))
        store.install()
        stores.tag_stores()  # tagged as made: a killed run's is dropped by the next to use the server
        lake = work / "lake"
        tenants = build_fleet(runs, store, stores, work / "sites", lake)
        lap("store_installed_and_24_sites_pushed")
        contents = store_contents(store)
        alpha = tenants["t-alpha"].pop("dsn")
        delta = tenants["t-delta"].pop("dsn")  # sent nothing: both senders are others to it (k counts no own rows)
        for t in tenants.values():
            t.pop("dsn", None)
        try:
            TenantStore(alpha).run("frequency")
            refusal = None
        except RefusedAggregate as exc:
            refusal = str(exc)
        store.set_min_customers(2)
        fleet_freq = TenantStore(delta).run("frequency", {"k": 2})
        similar_eval = held_out(runs, alpha)
        lap("queries_on_store_and_similar")
        probe = sorted(min(runs["held"].items())[1][1][0].effects.items())  # the first held-out fault's
        fence = fenced_lake(lake, "t-alpha")
        engines, spark_start = engines_on(lake, args.spark_on_fleet_lake and not args.no_spark)
        small = {"queries": compare_engines(engines, probe, ref, {"duckdb": 1, "spark": 1}),
                 "spark_session_s": spark_start}  # Spark against DuckDB here: tests/test_fleet_engines.py
        engines[0].close()
        lap("engines_on_fleet_lake")

        seeds = [r for t in ("t-alpha", "t-beta")  # the tenants whose policies send signatures
                 for r in rows_of(*(pq.read_table(lake / f"tenant={t}" / rel) for rel in ("signatures", "effects")))]
        sig, eff = synthetic_fleet(seeds, args.rows, tenants=8, days=30)
        big = work / "big"
        files = write_fleet(big, sig, eff)
        lap("synthesise_and_write_scale_lake")
        engines, spark_start = engines_on(big, not args.no_spark)  # Spark: one session for both lakes
        scale = {"queries": compare_engines(engines, probe, ref, {"duckdb": 3, "spark": 1}),
                 "spark_session_s": spark_start}
        for eng in engines:
            eng.close()
        lap("engines_at_scale")
        print(json.dumps({
            "sites": sum(t["sites"] for t in tenants.values()), "tenants": tenants,
            "real_runs": runs["runs"], "runs_made_now": runs["made"],
            "runs_make_s": round(runs["make_wall_s"], 1), "runs_make_cpu_s": round(runs["make_cpu_s"], 1),
            "site_runs_read_as_injected": sum(r.cause in [s.cause for s in sigs] for r, sigs in runs["site"].values()),
            "store": contents, "k_default_refusal": refusal, "fleet_frequency_k2": fleet_freq,
            "similar_held_out": similar_eval, "lake_as_t_alpha": fence, "engines_on_fleet_lake": small,
            "scale": {"signatures": args.rows, "effect_rows": eff.num_rows, "files": files, **scale},
            "reference_mj_step_s": ref, "phases": phases, "total_s": round(time.perf_counter() - t0, 1),
            "cpu_s": round(cpu_s(), 1), "spark_jvm_cpu_s": jvm_cpu_s(),
            "load_average_1min_start_end": [round(load0[0], 2), round(os.getloadavg()[0], 2)],
        }, indent=1, default=str))
    finally:
        shutil.rmtree(work, ignore_errors=True)
        left = stores.close()  # drops this run's store and frees the lock; names what is left, for the next to drop
        if left:
            print(left, file=sys.stderr)


if __name__ == "__main__":
    with ended_by_signals():  # SIGTERM, SIGHUP: the work folder removed and the store dropped, as on Ctrl-C
        main()
