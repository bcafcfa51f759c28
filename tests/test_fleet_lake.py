"""The Parquet lake under repeated and hostile writes and paths: each signature once however often
it is written, a lake path that holds a quote or SQL read as a path, a damaged file one line."""

from __future__ import annotations

import math
import shutil

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import ConfigError
from cellguard.fleet.duckdb_engine import DuckDBEngine
from cellguard.fleet.lake import EFFECTS, SIGNATURES, tenants, write_tables
from cellguard.fleet.landing import write_signatures
from cellguard.fleet.signature import Signature
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
    assert write_signatures(tmp_path, rows, "batch-2") == 0  # a retry rewrites its own file the same
    assert write_signatures(tmp_path, rows[:5], "batch-3") == 0  # moved into the file last written
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


# -- a tenant's folder holds only that tenant's rows, read without following a link --------------------------------


def hostile_lake(root, n: int = 120):
    """Five tenants; t4 alone has ``secret_cause``; t0's folder also holds rows that claim four other
    customers with it, and a link to t1's files; t1 a signature with non-finite effects (a lake written
    before signatures were checked)."""
    sig, eff = synthetic_fleet(SEEDS, n, tenants=5, sites_per_tenant=2, days=1, versions=1, seed=7)
    write_fleet(root, sig, eff)
    day = sig["created_date"][0].as_py()
    secret = Signature("t4", "t4-s0", day.isoformat(), "secret_cause", 0.9, "arm5", "arm-pick-place",
                       {"current_rms.elbow": 1.0}).to_dict() | {"signature_id": "secret"}
    odd = {**secret, "signature_id": "odd", "tenant_id": "t1", "site_id": "t1-s9", "cause": "odd",
           "effects": {"current_rms.elbow": float("nan"), "tracking_rms.elbow": float("inf")}}
    write_signatures(root, [secret, odd], "late")
    forged = [{**secret, "signature_id": f"forged{i}", "tenant_id": f"fake{i}", "created_date": day} for i in range(4)]
    pq.write_table(pa.Table.from_pylist(forged, SIGNATURES),
                   root / "tenant=t0" / "signatures" / f"date={day}" / "forged.parquet")
    forged_effects = [{**r, "feature": "current_rms.elbow", "effect": 1.0} for r in forged]
    pq.write_table(pa.Table.from_pylist(forged_effects, EFFECTS),
                   root / "tenant=t0" / "effects" / f"date={day}" / "forged.parquet")
    t1_file = next((root / "tenant=t1" / "signatures").rglob("*.parquet"))
    (root / "tenant=t0" / "signatures" / f"date={day}" / "link.parquet").symlink_to(t1_file)
    (root / "tenant=t0" / "signatures" / "date=2000-01-01").symlink_to(t1_file.parent)
    (root / "tenant=t9").symlink_to(root / "tenant=t1")
    return sig


def test_rows_that_name_another_tenant_than_their_folder_are_not_read(tmp_path):
    hostile_lake(tmp_path)
    secret = [r for r in DuckDBEngine(tmp_path).run("frequency", {"k": 1}) if r["cause"] == "secret_cause"]
    assert [(r["signatures"], r["customers"]) for r in secret] == [(1, 1)]
    as_t0 = DuckDBEngine(tmp_path, "t0", min_customers=4)  # four customers besides t0: it is answered at k=4
    assert "secret_cause" not in {r["cause"] for r in as_t0.run("frequency", {"k": 4})}
    assert "secret_cause" not in {r["cause"] for r in as_t0.run("frequency", scope="own")}


def test_a_link_in_a_tenant_folder_is_never_followed(tmp_path):
    sig = hostile_lake(tmp_path)
    for f in (tmp_path / "tenant=t1").rglob("*.parquet"):
        f.write_bytes(b"not parquet")  # t1's files: a query of t0's that opened one would fail
    own = DuckDBEngine(tmp_path, "t0").run("frequency", scope="own")
    assert sum(r["signatures"] for r in own) == sig["tenant_id"].to_pylist().count("t0")
    assert tenants(tmp_path) == ["t0", "t1", "t2", "t3", "t4"]  # tenant=t9, a link, is no customer


def test_a_non_finite_effect_in_the_lake_is_left_out_of_similar(tmp_path):
    hostile_lake(tmp_path)
    near = DuckDBEngine(tmp_path).run("similar", {"site": "none", "robot_model": "arm5", "limit": 500},
                                      [("current_rms.elbow", 5.0), ("tracking_rms.elbow", 1.5)])
    assert near and "odd" not in {r["signature_id"] for r in near}
    assert all(math.isfinite(r["similarity"]) for r in near)


def test_spark_reads_a_hostile_lake_as_duckdb_does_and_fails_in_one_line(tmp_path):
    pytest.importorskip("pyspark", reason="the Spark engine needs pyspark: pip install 'cellguard[spark]'")
    if shutil.which("java") is None:
        pytest.skip("the Spark engine needs Java 17")
    from cellguard.fleet.spark_engine import SparkEngine

    hostile_lake(tmp_path)
    with pytest.raises(ConfigError, match=r"--spark-master: 'bogus://x'; expected local"):
        SparkEngine(tmp_path, "bogus://x")
    probe = [("current_rms.elbow", 5.0), ("tracking_rms.elbow", 1.5)]
    spark = SparkEngine(tmp_path, "local[1]")
    try:
        near = {"site": "none", "robot_model": "arm5", "limit": 500}
        for name, params in (("frequency", {"k": 1}), ("similar", near)):
            assert spark.run(name, params, probe) == DuckDBEngine(tmp_path).run(name, params, probe), name
        assert SparkEngine(tmp_path, "local[1]", "t0").run("frequency", scope="own") == \
            DuckDBEngine(tmp_path, "t0").run("frequency", scope="own")
        next((tmp_path / "tenant=t2" / "signatures").rglob("*.parquet")).write_bytes(b"PAR1 not parquet at all")
        with pytest.raises(ConfigError, match="query frequency failed in Spark") as caught:
            spark.run("frequency", {"k": 1})
        assert "\n" not in str(caught.value)
    finally:
        spark.close()
    result = CliRunner().invoke(app, ["fleet", "query", "frequency", "--lake", str(tmp_path), "--engine", "spark",
                                      "--spark-master", "bogus://x"])
    assert result.exit_code == 2 and result.stderr.count("\n") == 1 and "--spark-master" in result.stderr


def test_cli_query_prints_text_from_the_lake_with_control_characters_escaped(tmp_path, fleet_tables):
    (row,) = rows_of(*fleet_tables)[:1]
    write_signatures(tmp_path, [{**row, "cause": "x\x1b[2J\x1b]0;owned\x07"}], "written-before-checks")
    result = CliRunner().invoke(app, ["fleet", "query", "frequency", "--lake", str(tmp_path), "--k", "1"])
    assert result.exit_code == 0, result.output
    assert "\x1b" not in result.stdout and "\x07" not in result.stdout and "cause=x\\x1b[2J" in result.stdout


def test_nothing_is_written_through_a_link_nor_withdrawn_past_one(tmp_path):
    """A tenant folder that is a link took pushes (written through it) but withdraw and retention skipped it:
    '0 signatures from the lake', exit 0, the rows still there."""
    from cellguard.errors import OutputError
    from cellguard.fleet.lake import forget

    elsewhere, lake = tmp_path / "volume", tmp_path / "lake"
    elsewhere.mkdir()
    lake.mkdir()
    (lake / "tenant=t0").symlink_to(elsewhere)
    rows = [r for r in rows_of(*synthetic_fleet(SEEDS, 20, tenants=1, sites_per_tenant=1, days=1, versions=1,
                                                seed=3)) if r["tenant_id"] == "t0"]
    with pytest.raises(OutputError, match=r"tenant=t0: is a link; cellguard never follows links in a lake"):
        write_signatures(lake, rows, "batch")
    assert list(elsewhere.iterdir()) == []
    (lake / "tenant=t0").unlink()
    write_signatures(lake, rows, "batch")
    date = next((lake / "tenant=t0" / "signatures").iterdir())
    date.rename(elsewhere / date.name)
    date.symlink_to(elsewhere / date.name)
    with pytest.raises(OutputError, match=r"date=.*: is a link"):
        forget(lake, "t0", rows[0]["site_id"])
