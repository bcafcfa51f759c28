"""The named queries on the Parquet lake with Apache Spark: local mode, or a cluster by URL.

``pyspark`` is an extra (``pip install 'cellguard[spark]'``, Java 17) imported only here.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

from cellguard.errors import ConfigError
from cellguard.fleet.lake import EFFECTS, SIGNATURES, has_data, lone_and_shared
from cellguard.fleet.queries import MIN_CUSTOMERS, named, plain, render
from cellguard.fleet.rights import access


def _pyspark():
    try:
        from pyspark.sql import SparkSession
    except ImportError:
        raise ConfigError("--engine spark: pyspark is not installed; pip install 'cellguard[spark]' "
                          "(needs Java 17)") from None
    return SparkSession


class SparkEngine:
    """Queries as ``tenant`` or the operator (``tenant`` None), as ``DuckDBEngine`` does (``rights.py``).
    One Spark session per process: a second engine reuses it until ``close``."""

    name = "spark"

    def __init__(self, lake: Path, master: str = "local[2]", tenant: str | None = None,
                 min_customers: int = MIN_CUSTOMERS):
        if not has_data(lake):
            raise ConfigError(f"--lake {lake}: no signatures in it (expected tenant=*/signatures/date=*/*.parquet)")
        self.lake, self.tenant, self.min_customers = Path(lake).resolve(), tenant, min_customers
        session = _pyspark()
        # Python workers run this interpreter (its packages, its version), not the first ``python3`` on PATH,
        # unless the user chose one; PySpark reads the variable when the session's context starts
        os.environ.setdefault("PYSPARK_PYTHON", sys.executable)
        self.spark = (session.builder.master(master).appName("cellguard-fleet")
                      .config("spark.ui.enabled", "false").config("spark.sql.session.timeZone", "UTC")
                      .config("spark.ui.showConsoleProgress", "false")
                      .config("spark.sql.shuffle.partitions", "8").config("spark.driver.bindAddress", "127.0.0.1")
                      .config("spark.driver.host", "127.0.0.1").getOrCreate())
        self.spark.sparkContext.setLogLevel("ERROR")

    def run(self, query: str, params: Mapping | None = None, probe: Sequence[tuple[str, float]] = (),
            scope: str = "fleet") -> list[dict]:
        q = named(query)
        allowed = access(self.lake, q, params, self.tenant, scope, self.min_customers)
        for rel, schema in (("signatures", SIGNATURES), ("effects", EFFECTS)):  # only what the caller may read
            # each row once, as DuckDB reads it: DISTINCT over the partitions that hold more than one file
            lone, shared = lone_and_shared(allowed.paths(self.lake, rel))
            self._read(lone, schema).unionByName(self._read(shared, schema).distinct()).createOrReplaceTempView(rel)
        self.spark.createDataFrame([(f, float(e)) for f, e in probe], "feature string, effect double") \
            .createOrReplaceTempView("probe")
        return [plain(r.asDict()) for r in self.spark.sql(render(q, allowed.params)).collect()]

    def _read(self, found: list[str], schema):
        """The listed files (the schema given: no footer is read to infer it, no partition column is added
        from the path), or an empty frame."""
        if not found:
            return self.spark.createDataFrame([], _ddl(schema))
        return self.spark.read.schema(_ddl(schema)).parquet(*found)

    def close(self) -> None:
        self.spark.stop()


_SPARK_TYPES = {"string": "string", "date32[day]": "date", "double": "double", "int64": "bigint", "int32": "int"}


def _ddl(schema) -> str:
    """The lake's arrow schema as a Spark DDL string."""
    return ", ".join(f"{f.name} {_SPARK_TYPES[str(f.type)]}" for f in schema)
