"""The named queries on the Parquet lake with Apache Spark: local mode, or a cluster by URL.

``pyspark`` is an extra (``pip install 'cellguard[spark]'``, Java 17) imported only here. A master
URL Spark would not take, a session that cannot start, a damaged file: a ConfigError in one line,
as on DuckDB.
"""

from __future__ import annotations

import os
import re
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

from cellguard.errors import ConfigError
from cellguard.fleet.lake import EFFECTS, SIGNATURES, has_data, read_groups
from cellguard.fleet.queries import MIN_CUSTOMERS, first_line, named, plain, render
from cellguard.fleet.rights import access

MASTER = re.compile(r"local(\[[0-9*, ]+\])?|yarn|(spark|k8s)://\S+")  # the forms Spark's submit takes


def _pyspark():
    try:
        from pyspark.sql import SparkSession
    except ImportError:
        raise ConfigError("--engine spark: pyspark is not installed; pip install 'cellguard[spark]' "
                          "(needs Java 17)") from None
    return SparkSession


def _spark_errors() -> tuple[type[Exception], ...]:
    """What Spark raises for a session that cannot start or a query that fails (Python side or JVM side)."""
    from py4j.protocol import Py4JError
    from pyspark.errors import PySparkException
    return PySparkException, Py4JError


def _why(exc: Exception) -> str:
    """A Spark failure in one line: the JVM's exception when there is one (py4j's own first line only
    says which call failed)."""
    java = getattr(exc, "java_exception", None)
    return first_line(java.toString() if java is not None else exc)


class SparkEngine:
    """Queries as ``tenant`` or the operator (``tenant`` None), as ``DuckDBEngine`` does (``rights.py``).
    One Spark session per process: a second engine reuses it until ``close``."""

    name = "spark"

    def __init__(self, lake: Path, master: str = "local[2]", tenant: str | None = None,
                 min_customers: int = MIN_CUSTOMERS):
        if not has_data(lake):
            raise ConfigError(f"--lake {lake}: no signatures in it (expected tenant=*/signatures/date=*/*.parquet)")
        if not isinstance(master, str) or not MASTER.fullmatch(master):
            raise ConfigError(f"--spark-master: {master!r}; expected local, local[N], spark://HOST:PORT, "
                              f"k8s://URL or yarn")
        self.lake, self.tenant, self.min_customers = Path(lake).resolve(), tenant, min_customers
        session = _pyspark()
        # Python workers run this interpreter (its packages, its version), not the first ``python3`` on PATH,
        # unless the user chose one; PySpark reads the variable when the session's context starts
        os.environ.setdefault("PYSPARK_PYTHON", sys.executable)
        try:
            self.spark = (session.builder.master(master).appName("cellguard-fleet")
                          .config("spark.ui.enabled", "false").config("spark.sql.session.timeZone", "UTC")
                          .config("spark.ui.showConsoleProgress", "false")
                          .config("spark.sql.shuffle.partitions", "8").config("spark.driver.bindAddress", "127.0.0.1")
                          .config("spark.driver.host", "127.0.0.1").getOrCreate())
        except _spark_errors() as exc:
            raise ConfigError(f"--spark-master {master}: Spark did not start ({_why(exc)})") from None
        self.spark.sparkContext.setLogLevel("OFF")  # a failure is reported in one line, not as the JVM's log

    def run(self, query: str, params: Mapping | None = None, probe: Sequence[tuple[str, float]] = (),
            scope: str = "fleet") -> list[dict]:
        from pyspark.sql.functions import col, lit

        q = named(query)
        allowed = access(self.lake, q, params, self.tenant, scope, self.min_customers)
        try:
            for rel, schema in (("signatures", SIGNATURES), ("effects", EFFECTS)):  # only what the caller may read
                # as DuckDB reads them: each row once, and only the rows that name their folder's tenant; the
                # schema given (no footer read to infer it, no partition column added from the path)
                source = self.spark.createDataFrame([], _ddl(schema))
                for tenant, found, shared in read_groups(allowed.paths(self.lake, rel), schema):
                    rows = self.spark.read.schema(_ddl(schema)).parquet(*found).filter(col("tenant_id") == lit(tenant))
                    source = source.unionByName(rows.distinct() if shared else rows)
                source.createOrReplaceTempView(rel)
            self.spark.createDataFrame([(f, float(e)) for f, e in probe], "feature string, effect double") \
                .createOrReplaceTempView("probe")
            return [plain(r.asDict()) for r in self.spark.sql(render(q, allowed.params, allowed.exprs)).collect()]
        except _spark_errors() as exc:
            raise ConfigError(f"--lake {self.lake}: query {q.name} failed in Spark ({_why(exc)})") from None

    def close(self) -> None:
        self.spark.stop()


_SPARK_TYPES = {"string": "string", "date32[day]": "date", "double": "double", "int64": "bigint", "int32": "int"}


def _ddl(schema) -> str:
    """The lake's arrow schema as a Spark DDL string."""
    return ", ".join(f"{f.name} {_SPARK_TYPES[str(f.type)]}" for f in schema)
