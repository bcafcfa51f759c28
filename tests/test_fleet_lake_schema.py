"""A lake holding a Parquet file whose columns are not the lake's (an extra column, a column of another type, a
missing one): each engine refuses it in one line naming the file, by one shared check (DuckDB failed with no file
named, or read the other type and counted its rows; Spark refused the other type only)."""

from __future__ import annotations

import shutil

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import ConfigError
from cellguard.fleet.duckdb_engine import DuckDBEngine
from cellguard.fleet.synthetic import synthetic_fleet, write_fleet

SEEDS = [{"cause": "friction", "robot_model": "arm5", "cell_type": "arm-pick-place", "confidence": 0.8,
          "onset_cycle": 7, "detection_delay_cycles": 2, "effects": {"current_rms.elbow": 6.0}}]


def odd(table: pa.Table, how: str) -> pa.Table:
    if how == "extra":
        return table.append_column("note", pa.array(["x"] * table.num_rows))
    if how == "type":
        return table.set_column(table.schema.get_field_index("confidence"), "confidence",
                                pc.cast(table["confidence"], pa.string()))
    return table.drop_columns(["recovery"])


@pytest.fixture
def lake(tmp_path):
    write_fleet(tmp_path, *synthetic_fleet(SEEDS, 20, tenants=2, sites_per_tenant=1, days=1, versions=1, seed=3))
    return tmp_path.resolve()  # Spark names the files by their resolved path


def plant(lake, how: str):
    """A second file beside a good one in t0's partition, its rows the good file's, its columns not the lake's."""
    good = next((lake / "tenant=t0" / "signatures").rglob("*.parquet"))
    bad = good.with_name("odd.parquet")
    pq.write_table(odd(pq.read_table(good, partitioning=None), how), bad)
    return bad


@pytest.mark.parametrize("how, said", [("extra", "column note is not one of the lake's"),
                                        ("type", "column confidence is string, the lake's is double"),
                                        ("missing", "it has no column recovery")])
def test_duckdb_refuses_a_file_of_other_columns_naming_it(lake, how, said):
    before = DuckDBEngine(lake).run("frequency", {"k": 1})
    bad = plant(lake, how)
    with pytest.raises(ConfigError) as caught:
        DuckDBEngine(lake).run("frequency", {"k": 1})
    assert str(caught.value).startswith(f"lake file {bad}: {said};") and "\n" not in str(caught.value)
    result = CliRunner().invoke(app, ["fleet", "query", "frequency", "--lake", str(lake), "--k", "1"])
    assert result.exit_code == 2 and result.stderr.count("\n") == 1 and str(bad) in result.stderr
    bad.unlink()
    assert DuckDBEngine(lake).run("frequency", {"k": 1}) == before  # the lake's own files still read


def test_a_tenant_is_refused_only_for_files_it_may_read(lake):
    before = DuckDBEngine(lake, "t0").run("frequency", scope="own")
    theirs = next((lake / "tenant=t1" / "signatures").rglob("*.parquet"))
    pq.write_table(odd(pq.read_table(theirs, partitioning=None), "extra"), theirs)
    assert DuckDBEngine(lake, "t0").run("frequency", scope="own") == before  # t1's file is not t0's to read or name
    with pytest.raises(ConfigError, match=f"lake file {theirs}: column note"):
        DuckDBEngine(lake).run("frequency", {"k": 1})  # the operator reads it


def test_spark_refuses_the_same_file_in_the_same_line(lake):
    pytest.importorskip("pyspark", reason="the Spark engine needs pyspark: pip install 'cellguard[spark]'")
    if shutil.which("java") is None:
        pytest.skip("the Spark engine needs Java 17")
    from cellguard.fleet.spark_engine import SparkEngine

    bad = plant(lake, "extra")
    with pytest.raises(ConfigError) as duck:
        DuckDBEngine(lake).run("frequency", {"k": 1})
    spark = SparkEngine(lake, "local[1]")
    try:
        with pytest.raises(ConfigError) as caught:
            spark.run("frequency", {"k": 1})
    finally:
        spark.close()
    assert str(caught.value) == str(duck.value) and str(bad) in str(caught.value)
