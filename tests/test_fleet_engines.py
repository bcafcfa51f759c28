"""One set of named queries, the same answers on every engine: DuckDB against Spark (local mode)
on a Parquet lake, and DuckDB against PostgreSQL under row-level security."""

from __future__ import annotations

import math
import os
import shutil

import pytest

from cellguard.errors import ConfigError, UnknownNameError
from cellguard.fleet.duckdb_engine import DuckDBEngine
from cellguard.fleet.queries import QUERIES, RefusedAggregate, named, render
from cellguard.fleet.synthetic import rows_of, synthetic_fleet, write_fleet

SEEDS = [
    {"cause": "friction", "robot_model": "arm5", "cell_type": "arm-pick-place", "confidence": 0.8,
     "onset_cycle": 7, "detection_delay_cycles": 2, "effects": {"current_rms.elbow": 6.0, "tracking_rms.elbow": 1.1}},
    {"cause": "fixture_shift", "robot_model": "arm5", "cell_type": "arm-pick-place", "confidence": 0.9,
     "onset_cycle": 7, "detection_delay_cycles": 0, "effects": {"part_seen_x_mm": 11.0, "grasp_tcp_x_mm": 5.0}},
    {"cause": "servo", "robot_model": "quad12", "cell_type": "quadruped-turns", "confidence": 0.7,
     "onset_cycle": 16, "detection_delay_cycles": 3, "effects": {"tracking_rms.lf_knee": 8.0, "current_rms.lf_knee": 0.4}},
]
PROBE = [("current_rms.elbow", 5.0), ("tracking_rms.elbow", 1.5)]
PARAMS = {"frequency": {"k": 2}, "introduced": {"k": 2}, "fixes": {"k": 2},
          "similar": {"site": "t0-s0", "robot_model": "arm5", "limit": 7}}


@pytest.fixture(scope="module")
def lake(tmp_path_factory):
    sig, eff = synthetic_fleet(SEEDS, 400, tenants=3, sites_per_tenant=3, days=3, versions=2, seed=3)
    root = tmp_path_factory.mktemp("lake")
    write_fleet(root, sig, eff)
    return root, sig, eff


def equal(a: list[dict], b: list[dict]) -> bool:
    return len(a) == len(b) and all(
        x.keys() == y.keys() and all(math.isclose(x[k], y[k], rel_tol=1e-9) if isinstance(x[k], float) else x[k] == y[k]
                                     for k in x) for x, y in zip(a, b))


def test_duckdb_answers_are_consistent_with_the_data(lake):
    root, sig, _ = lake
    eng = DuckDBEngine(root)
    freq = eng.run("frequency", {"k": 2})
    assert sum(r["signatures"] for r in freq) == sig.num_rows  # 3 customers: every group passes k=2
    assert all(r["customers"] >= 2 for r in freq)
    assert eng.run("frequency", {"k": 4}) == []  # no group has 4 customers
    near = eng.run("similar", PARAMS["similar"], PROBE)
    assert len(near) == 7 and all(r["site_id"] != "t0-s0" for r in near)
    assert [r["cause"] for r in near] == ["friction"] * 7
    assert near == sorted(near, key=lambda r: -r["similarity"])
    intro = eng.run("introduced", {"k": 2})
    assert {r["cause"] for r in intro} == {"friction", "fixture_shift", "servo"}
    assert all(r["first_seen"] == "2026-10-01" and r["deployed"] == "2026-10-01" for r in intro)  # day 0 has pv0, pv1


def test_queries_refuse_unknown_names_and_unsafe_parameters():
    with pytest.raises(UnknownNameError, match="unknown fleet query 'everything'; known: fixes, frequency"):
        named("everything")
    with pytest.raises(ConfigError, match="parameter site must match"):
        render(QUERIES["similar"], {"site": "x' OR '1'='1"})
    with pytest.raises(ConfigError, match="parameter 'tenant' unknown"):
        render(QUERIES["frequency"], {"tenant": "t0"})
    with pytest.raises(ConfigError, match="parameter k must be 1..1000000"):
        render(QUERIES["frequency"], {"k": 0})


def test_duckdb_and_spark_agree_on_every_query(lake, tmp_path, monkeypatch):
    pytest.importorskip("pyspark", reason="the Spark engine needs pyspark: pip install 'cellguard[spark]'")
    from cellguard.fleet.spark_engine import SparkEngine

    # the first python3 on PATH is not this interpreter (another version, no pyarrow): Spark's Python
    # workers must still run this one
    for name in ("python3", "python"):
        shim = tmp_path / "bin" / name
        shim.parent.mkdir(exist_ok=True)
        shim.write_text("#!/bin/sh\necho 'a python3 from PATH ran' >&2\nexit 3\n")
        shim.chmod(0o755)
    monkeypatch.setenv("PATH", f"{tmp_path / 'bin'}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.delenv("PYSPARK_PYTHON", raising=False)
    root, _, _ = lake
    duck, spark = DuckDBEngine(root), SparkEngine(root, "local[2]")
    try:
        for name in QUERIES:
            a = duck.run(name, PARAMS[name], PROBE)
            b = spark.run(name, PARAMS[name], PROBE)
            assert a and equal(a, b), name
        # with a tenant's rights: the same fence on both (the second engine reuses the session)
        duck_t0, spark_t0 = DuckDBEngine(root, "t0", min_customers=2), SparkEngine(root, "local[2]", "t0", 2)
        for name in QUERIES:
            for scope in ("fleet", "own"):
                a = duck_t0.run(name, PARAMS[name], PROBE, scope=scope)
                assert a and equal(a, spark_t0.run(name, PARAMS[name], PROBE, scope=scope)), (name, scope)
        with pytest.raises(RefusedAggregate, match="fewer than 5 customers"):
            SparkEngine(root, "local[2]", "t0").run("fixes", {"k": 2})
    finally:
        spark.close()


def test_a_tenant_reads_its_own_lake_folder_only(lake, tmp_path):
    root, sig, _ = lake
    fenced = tmp_path / "lake"
    shutil.copytree(root, fenced)
    assert {p.name: p.stat().st_mode & 0o777 for p in root.glob("tenant=*")} == \
        {f"tenant=t{i}": 0o700 for i in range(3)}  # one owner-only folder per tenant
    for other in ("t1", "t2"):  # another tenant's files, unreadable: a query that opened one would fail
        for f in (fenced / f"tenant={other}").rglob("*.parquet"):
            f.write_bytes(b"not parquet")
    t0 = DuckDBEngine(fenced, "t0")
    near = t0.run("similar", {"site": "t0-s0", "robot_model": "arm5", "limit": 50}, PROBE)
    assert near and {r["site_id"].split("-")[0] for r in near} == {"t0"}
    own = t0.run("frequency", scope="own")
    assert sum(r["signatures"] for r in own) == sum(t == "t0" for t in sig["tenant_id"].to_pylist())
    with pytest.raises(Exception, match="(?i)parquet|magic"):  # the operator reads every folder
        DuckDBEngine(fenced).run("frequency", {"k": 1})
    for bad in ("*", "t0/../t1", "T0"):  # a tenant id is an id, never a glob or a path
        with pytest.raises(ConfigError, match="tenant: expected an opaque id"):
            DuckDBEngine(fenced, bad).run("similar", scope="own")


def test_a_tenant_gets_cross_customer_rows_only_over_k_customers(lake):
    root, _, _ = lake  # 3 customers
    operator = DuckDBEngine(root)
    with pytest.raises(RefusedAggregate, match="^cross-customer query frequency refused: signatures from fewer than 5 customers$"):
        DuckDBEngine(root, "t0").run("frequency", {"k": 2})  # the lake's least (5) wins over the k asked
    with pytest.raises(RefusedAggregate, match="fewer than 4 customers"):
        DuckDBEngine(root, "t0", min_customers=2).run("introduced", {"k": 4})
    with pytest.raises(RefusedAggregate, match="fewer than 3 customers"):
        DuckDBEngine(root, "t0", min_customers=3).run("frequency", {"k": 1})  # its own folder counts toward no k
    t9 = DuckDBEngine(root, "t9", min_customers=3)  # holds nothing in the lake: its 3 customers are others
    for name in ("frequency", "introduced", "fixes"):
        rows = t9.run(name, {"k": 1})  # asked for 1, given 3
        assert rows == operator.run(name, {"k": 3}), name
        assert all(r["customers"] >= 3 for r in rows)
    with pytest.raises(ConfigError, match="--scope: 'all'"):
        t9.run("frequency", scope="all")


def test_duckdb_and_postgresql_agree_within_one_tenants_rights(lake, tmp_path):
    from fleet_server import admin_dsn_or_skip, store_name

    from cellguard.fleet.export import Batch
    from cellguard.fleet.store import FleetStore, TenantStore

    dsn = admin_dsn_or_skip()
    _, sig, eff = lake
    rows = [r for r in rows_of(sig, eff) if r["tenant_id"] == "t0"]
    store = FleetStore(dsn, store_name("engines"))
    store.install(reset=True)
    tenant = TenantStore(store.add_tenant("t0"))
    for site in sorted({r["site_id"] for r in rows}):
        tenant.push(Batch("t0", site, "v", "signatures", tuple(r for r in rows if r["site_id"] == site)))
    own = tmp_path / "own"
    import pyarrow.compute as pc
    keep = pc.equal(sig["tenant_id"], "t0")
    write_fleet(own, sig.filter(keep), eff.filter(pc.equal(eff["tenant_id"], "t0")))
    duck = DuckDBEngine(own)
    for name in QUERIES:
        params = {**PARAMS[name], "k": 1} if "k" in PARAMS[name] else PARAMS[name]
        a = duck.run(name, params, PROBE)
        b = tenant.run(name, params, PROBE, scope="own")
        assert a and equal(a, b), name
