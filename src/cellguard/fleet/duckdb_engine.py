"""The named queries on the Parquet lake with DuckDB: the default, one machine, in process."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import duckdb
import pyarrow as pa

from cellguard.errors import ConfigError
from cellguard.fleet.lake import has_data
from cellguard.fleet.queries import MIN_CUSTOMERS, named, plain, render
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
            self.con.execute(f"SET threads = {int(threads)}")

    def run(self, query: str, params: Mapping | None = None, probe: Sequence[tuple[str, float]] = (),
            scope: str = "fleet") -> list[dict]:
        q = named(query)
        allowed = access(self.lake, q, params, self.tenant, scope, self.min_customers)
        for rel, glob in allowed.globs.items():  # the views read only what the caller may read
            self.con.execute(f"CREATE OR REPLACE TEMP VIEW {rel} AS "
                             f"SELECT * FROM read_parquet('{glob}', hive_partitioning = false)")
        table = pa.table({"feature": pa.array([f for f, _ in probe], pa.string()),
                          "effect": pa.array([float(e) for _, e in probe], pa.float64())})
        self.con.register("probe", table)
        try:
            cur = self.con.execute(render(q, allowed.params))
            cols = [d[0] for d in cur.description]
            return [plain(dict(zip(cols, r))) for r in cur.fetchall()]
        finally:
            self.con.unregister("probe")

    def close(self) -> None:
        self.con.close()
