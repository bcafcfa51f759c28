"""The named queries on the Parquet lake with DuckDB: the default, one machine, in process.

The views are built with DuckDB's relation API from the listed files, never by writing a path
into SQL text: a lake path holding a quote or SQL is a path like any other. Each view reads a
row once (``DISTINCT`` over the partitions that hold more than one file) and only the rows of
each tenant folder that name its tenant (``lake.read_groups``). A DuckDB error is a ConfigError
in one line.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import duckdb
import pyarrow as pa

from cellguard.errors import ConfigError
from cellguard.fleet.lake import EFFECTS, SIGNATURES, has_data, read_groups
from cellguard.fleet.queries import MIN_CUSTOMERS, first_line, named, plain, render
from cellguard.fleet.rights import access


class DuckDBEngine:
    """Queries as ``tenant`` (its own rows; cross-customer aggregates over at least k customers),
    or as the operator (``tenant`` None: every row); see ``rights.py``."""

    name = "duckdb"

    def __init__(self, lake: Path, tenant: str | None = None, threads: int | None = None,
                 min_customers: int = MIN_CUSTOMERS):
        if not has_data(lake):
            raise ConfigError(f"--lake {lake}: no signatures in it (expected tenant=*/signatures/date=*/*.parquet)")
        self.lake, self.tenant, self.min_customers = Path(lake), tenant, min_customers
        self.con = duckdb.connect()
        if threads:
            self.con.execute("SET threads = ?", [int(threads)])

    def run(self, query: str, params: Mapping | None = None, probe: Sequence[tuple[str, float]] = (),
            scope: str = "fleet") -> list[dict]:
        q = named(query)
        allowed = access(self.lake, q, params, self.tenant, scope, self.min_customers)
        try:
            for rel, schema in (("signatures", SIGNATURES), ("effects", EFFECTS)):  # only what the caller may read
                source = self.con.from_arrow(schema.empty_table())
                for tenant, found, shared in read_groups(allowed.paths(self.lake, rel), schema):
                    rows = self.con.read_parquet(found, hive_partitioning=False).filter(
                        duckdb.ColumnExpression("tenant_id") == duckdb.ConstantExpression(tenant))
                    source = source.union(rows.distinct() if shared else rows)
                source.create_view(rel, replace=True)
            table = pa.table({"feature": pa.array([f for f, _ in probe], pa.string()),
                              "effect": pa.array([float(e) for _, e in probe], pa.float64())})
            self.con.register("probe", table)
            try:
                cur = self.con.execute(render(q, allowed.params, allowed.exprs))
                cols = [d[0] for d in cur.description]
                return [plain(dict(zip(cols, r))) for r in cur.fetchall()]
            finally:
                self.con.unregister("probe")
        except duckdb.Error as exc:
            raise ConfigError(f"--lake {self.lake}: query {q.name} failed in DuckDB ({first_line(exc)})") from None

    def close(self) -> None:
        self.con.close()
