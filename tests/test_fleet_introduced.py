"""``introduced`` applies k before it takes a minimum: no date of a group seen at fewer than k customers
reaches its rows (DuckDB on a lake; the same SQL runs on PostgreSQL and Spark, compared in
``test_fleet_engines.py``)."""

from __future__ import annotations

import pytest

from cellguard.fleet.duckdb_engine import DuckDBEngine
from cellguard.fleet.landing import write_signatures
from cellguard.fleet.signature import Signature

KEY = b"site-secret-of-the-tests"


def land(lake, tenant: str, day: str, cause: str, version: str) -> None:
    sig = Signature(tenant, f"{tenant}-s", day, cause, 0.8, "arm5", "pick", {"x": 1.0}, 1, 0, version, "c", "0.1.0")
    write_signatures(lake, [{"signature_id": sig.signature_id(KEY), **sig.to_dict()}], f"{tenant}-{cause}-{day}")


@pytest.fixture
def lake(tmp_path):
    for i in range(5):  # five customers saw friction under pv1 from 2026-03-01 on
        land(tmp_path, f"t{i}", "2026-03-01", "friction", "pv1")
    return tmp_path


def introduced(lake) -> list[dict]:
    return DuckDBEngine(lake).run("introduced", {"k": 5})


def test_one_customers_old_signature_does_not_hide_a_cause(lake):
    before = introduced(lake)
    land(lake, "t6", "2020-01-01", "friction", "pv-evil")  # one customer, dated long before
    assert introduced(lake) == before == [{"cause": "friction", "policy_version": "pv1", "deployed": "2026-03-01",
                                           "first_seen": "2026-03-01", "signatures": 5, "sites": 5, "customers": 5}]


def test_a_lone_customers_date_does_not_show_as_deployed(lake):
    land(lake, "t7", "2021-03-14", "rare_private_cause", "pv1")  # a group of one, under a shared version
    (row,) = introduced(lake)
    assert row["deployed"] == "2026-03-01" and "2021-03-14" not in str(introduced(lake))
