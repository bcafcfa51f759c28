"""A batch queued while the store was down reaches the retention's edge row by row. Held whole for one row past
the retention, its rows within were held with it for good (time only makes more of them old): the signatures within
the retention are sent, those past it are dropped, counted in the audit log and in one line. A batch with every row
past the retention, or of counts (aggregates), is held whole, as before. Against a real PostgreSQL server (``.ci/fleet.sh`` starts one); the
store's date is the one the retention counts on, so the batches are queued under a host date days before it."""

from __future__ import annotations

import datetime as dt

import pyarrow.parquet as pq
import pytest

psycopg = pytest.importorskip("psycopg", reason="the fleet store tests need psycopg: pip install 'cellguard[fleet]'")

from cellguard.fleet.audit import read_audit  # noqa: E402
from cellguard.fleet.outbox import Outbox  # noqa: E402
from cellguard.fleet.policy import DataPolicy  # noqa: E402
from cellguard.fleet.push import push  # noqa: E402
from cellguard.fleet.signature import Signature  # noqa: E402
from cellguard.fleet.store import FleetStore, TenantStore  # noqa: E402
from fleet_server import admin_dsn_or_skip, store_name  # noqa: E402

DAYS = 30


@pytest.fixture(scope="module")
def fleet():
    store = FleetStore(admin_dsn_or_skip(), store_name("ret_edge"))
    store.install(reset=True)
    dsn = store.add_tenant("ta")
    return store, dsn, TenantStore(dsn).today()


def sig(site: str, day: dt.date, cause: str, n: int = 0) -> Signature:
    return Signature("ta", site, day.isoformat(), cause, 0.8, "arm5", "arm-pick-place", {"current_rms.elbow": 6.0 + n})


def stored(store: FleetStore, site: str) -> dict[str, list]:
    with store.admin() as con:
        return {"signatures": sorted(r[0].isoformat() for r in con.execute(
                    "SELECT created_date FROM fleet.signatures WHERE site_id = %s", (site,)).fetchall()),
                "aggregates": sorted(con.execute("SELECT month, signatures FROM fleet.aggregates WHERE site_id = %s",
                                                 (site,)).fetchall())}


def queued_on(site_dir, policy: DataPolicy, signatures: list[Signature], day: dt.date) -> str:
    """Queue the export of ``signatures`` as a push with no store on ``day`` did; the queued batch's id."""
    first = push(signatures, policy, site_dir, None, today=day)
    assert first.queued == 1 and first.batch.withheld_rows == 0  # every row inside the retention on ``day``
    return first.batch.batch_id


def test_a_queued_batch_at_the_retention_edge_sends_the_rows_within(fleet, tmp_path):
    store, dsn, today = fleet
    policy = DataPolicy("ta", "s-edge", retention_days=DAYS)
    edge, fresh = today - dt.timedelta(days=DAYS + 2), today - dt.timedelta(days=2)
    queued = queued_on(tmp_path / "site", policy, [sig("s-edge", edge, "friction"), sig("s-edge", fresh, "servo")],
                       today - dt.timedelta(days=2))  # two days ago: the edge row was inside the retention then
    lake = tmp_path / "lake"
    result = push([], policy, tmp_path / "site", TenantStore(dsn), lake=lake)
    assert (result.sent_batches, result.new_rows, result.queued, result.held) == (1, 1, 0, ())
    assert stored(store, "s-edge")["signatures"] == [fresh.isoformat()]  # never the row past the retention
    dates = sorted(p.parent.name for p in lake.rglob("signatures/date=*/*.parquet") if pq.read_table(p).num_rows)
    assert dates == [f"date={fresh.isoformat()}"]  # the lake holds what the store holds
    sent = read_audit(tmp_path / "site")[-1]
    assert (sent["status"], sent["rows"], sent["trimmed_from"]) == ("sent", 1, queued)
    assert sent["withheld_rows"] == 1 and "1 row(s) older than the policy's retention_days (30) not sent" in \
        sent["reason"], sent
    (line,) = result.trimmed
    assert queued in line and "\n" not in line and not Outbox(tmp_path / "site").count()


def test_a_queued_batch_of_counts_at_the_retention_edge_is_held_whole(fleet, tmp_path):
    """Counts are never trimmed: a month's count replaces the store's, and an older batch's counts sent after a newer
    one's put back the older figures (trimmed and sent late, one friction count fell from 3 to 2 and the month's
    servo count was deleted)."""
    store, dsn, today = fleet
    policy = DataPolicy("ta", "s-agg", export="aggregates_only", min_group_size=2, retention_days=DAYS)
    first_kept = (today - dt.timedelta(days=DAYS)).replace(day=1)  # the first day of the oldest month kept now
    then = first_kept + dt.timedelta(days=DAYS - 1)  # queued when the month before was still kept
    old, fresh = first_kept - dt.timedelta(days=1), today - dt.timedelta(days=DAYS)
    queued_on(tmp_path, policy, [sig("s-agg", d, "friction", i) for i, d in enumerate((old, old, fresh, fresh))], then)
    result = push([], policy, tmp_path, TenantStore(dsn))
    assert (result.sent_batches, result.queued, len(result.held), result.trimmed) == (0, 1, 1, ())
    assert stored(store, "s-agg") == {"signatures": [], "aggregates": []}


def test_a_queued_batch_wholly_past_the_retention_is_held_whole(fleet, tmp_path):
    store, dsn, today = fleet
    policy = DataPolicy("ta", "s-old", retention_days=DAYS)
    queued_on(tmp_path, policy, [sig("s-old", today - dt.timedelta(days=DAYS + 2), "friction")],
              today - dt.timedelta(days=2))
    result = push([], policy, tmp_path, TenantStore(dsn))
    assert (result.sent_batches, result.queued, len(result.held), result.trimmed) == (0, 1, 1, ())
    assert "1 row(s) older than the policy's retention_days (30)" in result.held[0]
    assert stored(store, "s-old") == {"signatures": [], "aggregates": []}
