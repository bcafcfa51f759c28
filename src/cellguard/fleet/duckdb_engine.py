"""The named queries on the Parquet lake with DuckDB: the default, one machine, in process."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import duckdb
import pyarrow as pa

from cellguard.errors import ConfigError
from cellguard.fleet.lake import has_data
from cellguard.fleet.queries import named, plain, render


class DuckDBEngine:
    name = "duckdb"

    def __init__(self, lake: Path, threads: int | None = None):
        if not has_data(lake):
            raise ConfigError(f"--lake {lake}: no signatures in it (expected signatures/date=*/tenant=*/*.parquet)")
        self.con = duckdb.connect()
        if threads:
            self.con.execute(f"SET threads = {int(threads)}")
        for rel in ("signatures", "effects"):
            glob = str(Path(lake) / rel / "*" / "*" / "*.parquet")
            self.con.execute(f"CREATE VIEW {rel} AS SELECT * FROM read_parquet('{glob}', hive_partitioning = false)")

    def run(self, query: str, params: Mapping | None = None, probe: Sequence[tuple[str, float]] = ()) -> list[dict]:
        q = named(query)
        table = pa.table({"feature": pa.array([f for f, _ in probe], pa.string()),
                          "effect": pa.array([float(e) for _, e in probe], pa.float64())})
        self.con.register("probe", table)
        try:
            cur = self.con.execute(render(q, params))
            cols = [d[0] for d in cur.description]
            return [plain(dict(zip(cols, r))) for r in cur.fetchall()]
        finally:
            self.con.unregister("probe")

    def close(self) -> None:
        self.con.close()
