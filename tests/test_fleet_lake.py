"""The Parquet lake under repeated and hostile writes and paths: each signature once however often
it is written, a lake path that holds a quote or SQL read as a path, a damaged file one line."""

from __future__ import annotations

import shutil

import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import ConfigError
from cellguard.fleet.duckdb_engine import DuckDBEngine
from cellguard.fleet.lake import write_signatures, write_tables
from cellguard.fleet.synthetic import rows_of, synthetic_fleet, write_fleet

SEEDS = [
    {"cause": "friction", "robot_model": "arm5", "cell_type": "arm-pick-place", "confidence": 0.8,
     "onset_cycle": 7, "detection_delay_cycles": 2, "effects": {"current_rms.elbow": 6.0, "tracking_rms.elbow": 1.1}},
    {"cause": "servo", "robot_model": "quad12", "cell_type": "quadruped-turns", "confidence": 0.7,
     "onset_cycle": 16, "detection_delay_cycles": 3, "effects": {"tracking_rms.lf_knee": 8.0}},
]


@pytest.fixture(scope="module")
def fleet_tables():
    return synthetic_fleet(SEEDS, 60, tenants=2, sites_per_tenant=2, days=1, versions=1, seed=5)


def total(eng, **kw) -> int:
    return sum(r["signatures"] for r in eng.run("frequency", {"k": 1}, **kw))


# -- F5: each signature once ---------------------------------------------------------------------------------------


def test_a_growing_set_written_again_adds_only_its_new_signatures(tmp_path, fleet_tables):
    rows = [r for r in rows_of(*fleet_tables) if r["tenant_id"] == "t0"]
    assert len(rows) > 10
    assert write_signatures(tmp_path, rows[:10], "batch-1") == 10
    assert write_signatures(tmp_path, rows, "batch-2") == len(rows) - 10
    assert write_signatures(tmp_path, rows, "batch-2") == len(rows) - 10  # a retry rewrites its own file the same
    assert write_signatures(tmp_path, rows[:5], "batch-3") == 0
    ids = pq.ParquetDataset(str(tmp_path / "tenant=t0" / "signatures")).read().column("signature_id").to_pylist()
    assert sorted(ids) == sorted(r["signature_id"] for r in rows)
    effects = pq.ParquetDataset(str(tmp_path / "tenant=t0" / "effects")).read()
    assert effects.num_rows == sum(len(r["effects"]) for r in rows)
    assert total(DuckDBEngine(tmp_path)) == len(rows)


def test_a_lake_holding_a_signature_twice_is_read_once_by_every_engine(tmp_path, fleet_tables):
    sig, eff = fleet_tables
    write_fleet(tmp_path, sig, eff, "first")
    write_fleet(tmp_path, sig, eff, "again")  # as a lake written before each signature was kept once
    duck = DuckDBEngine(tmp_path)
    assert total(duck) == sig.num_rows
    probe = [("current_rms.elbow", 5.0), ("tracking_rms.elbow", 1.5)]
    near = duck.run("similar", {"site": "nowhere", "robot_model": "arm5", "limit": 1000}, probe)
    assert len(near) == len({r["signature_id"] for r in near}) > 0
    pytest.importorskip("pyspark", reason="the Spark engine needs pyspark: pip install 'cellguard[spark]'")
    if shutil.which("java") is None:
        pytest.skip("the Spark engine needs Java 17")
    from cellguard.fleet.spark_engine import SparkEngine

    spark = SparkEngine(tmp_path, "local[1]")
    try:
        assert total(spark) == sig.num_rows
    finally:
        spark.close()


# -- F6: the lake's path is a path, never SQL ----------------------------------------------------------------------


def test_a_lake_path_with_a_quote_is_read(tmp_path, fleet_tables):
    lake = tmp_path / "it's a lake"
    write_fleet(lake, *fleet_tables)
    assert total(DuckDBEngine(lake)) == fleet_tables[0].num_rows
    assert total(DuckDBEngine(lake, "t0"), scope="own") == fleet_tables[0]["tenant_id"].to_pylist().count("t0")


def test_a_crafted_lake_path_cannot_read_another_tenants_rows(tmp_path, fleet_tables):
    sig, eff = fleet_tables
    other = tmp_path / "other"  # t1's folder, which t0's query must never read
    write_fleet(other, sig, eff)
    shutil.rmtree(other / "tenant=t0")
    crafted = tmp_path / (f"X') UNION ALL SELECT * FROM read_parquet('{other}/tenant=t1/signatures/date=*/*.parquet')"
                          " UNION ALL SELECT * FROM read_parquet('X")
    t0_sig = sig.filter(pc.equal(sig["tenant_id"], "t0"))
    write_tables(crafted, t0_sig, eff.filter(pc.equal(eff["tenant_id"], "t0")), "t0")
    rows = DuckDBEngine(crafted, "t0").run("frequency", scope="own")
    assert sum(r["signatures"] for r in rows) == t0_sig.num_rows
    assert {r["customers"] for r in rows} == {1}


def test_a_damaged_lake_file_is_one_line(tmp_path, fleet_tables):
    write_fleet(tmp_path, *fleet_tables)
    (next((tmp_path / "tenant=t0" / "signatures").rglob("*.parquet"))).write_bytes(b"PAR1 not parquet at all")
    with pytest.raises(ConfigError, match="query frequency failed in DuckDB") as caught:
        DuckDBEngine(tmp_path).run("frequency", {"k": 1})
    assert "\n" not in str(caught.value)
    result = CliRunner().invoke(app, ["fleet", "query", "frequency", "--lake", str(tmp_path), "--k", "1"])
    assert result.exit_code == 2 and result.stderr.count("\n") == 1 and "failed in DuckDB" in result.stderr
