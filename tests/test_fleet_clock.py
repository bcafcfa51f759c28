"""A site's or the store's wall clock set wrong during a push: retention counts its days on the store's clock and
deletes nothing by a date it cannot trust (a clock a year fast emptied the store and the lake, silently, exit 0),
says and logs what it deleted; with the two dates more than a day apart nothing is sent either (a store a year slow
let a signature past the retention leave; a year fast, it held a batch queued with a right clock); the batch is
queued before the store is asked (a store that never answered, then Ctrl-C, left nothing); queued batches go in
the order they were queued, whatever the clock did meanwhile (a batch written under a fast clock was sent last and
its stale count replaced the newer one).

A store whose clock is wrong is the tests' own database with ``fleet.now()`` shifted (``store_clock_off``): the
store's date and its retention's cutoff are read from SQL ``now()`` in the tenant's session, whose search path
puts ``fleet`` before ``pg_catalog``; checked against a server run under libfaketime, it behaves the same."""

from __future__ import annotations

import contextlib
import datetime as dt
import json
import os
import socket
import subprocess
import sys
import time

import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from cellguard import dates
from cellguard.cli import app
from cellguard.fleet.audit import read_audit
from cellguard.fleet.export import export_batch
from cellguard.fleet.landing import write_signatures
from cellguard.fleet.outbox import Outbox
from cellguard.fleet.policy import DataPolicy
from cellguard.fleet.push import push
from cellguard.fleet.signature import Signature, withhold
from cellguard.fleet.store import FleetStore, TenantStore
from fleet_server import admin_dsn_or_skip, store_name

KEY = b"site-secret-of-the-tests"  # the site key signature ids are keyed with (site_key.py)
HOST_TODAY = dt.datetime.now(dt.timezone.utc).date()


def sig(tenant: str, site: str, day: dt.date, cause: str = "friction", n: int = 0) -> Signature:
    return Signature(tenant, site, day.isoformat(), cause, 0.8, "arm5", "arm-pick-place",
                     {"current_rms.elbow": 6.0 + n}, 7, 1, "pv-1", "cal-1", "0.1.0")


def aged(tenant: str, site: str, today: dt.date, *days: int) -> list[Signature]:
    return [sig(tenant, site, today - dt.timedelta(days=d), n=i) for i, d in enumerate(days)]


def lake_rows(lake) -> int:
    return sum(pq.read_table(f).num_rows for f in (lake / "tenant=ta" / "signatures").rglob("*.parquet"))


@pytest.fixture(scope="module")
def fleet():
    store = FleetStore(admin_dsn_or_skip(), store_name("clock"))
    store.install(reset=True)
    with store.admin() as con:  # the server's date: the tests' "today" wherever the host's differs
        today = con.execute("SELECT (now() AT TIME ZONE 'UTC')::date").fetchone()[0]
    return store, store.add_tenant("ta"), today


def stored(store, site: str) -> int:
    with store.admin() as con:
        return con.execute("SELECT count(*) FROM fleet.signatures WHERE site_id = %s", (site,)).fetchone()[0]


@contextlib.contextmanager
def store_clock_off(fleet, days: int):
    """The store's clock ``days`` off, as on a server whose clock is set wrong: every date its tenants' statements
    read (``TenantStore.today``, the retention's cutoff) comes from ``now()``, here ``fleet.now()``."""
    store, dsn, today = fleet
    with store.admin() as con:
        con.execute("CREATE FUNCTION fleet.now() RETURNS timestamptz LANGUAGE sql STABLE AS "
                    f"$$ SELECT pg_catalog.now() + interval '{int(days)} days' $$")
        con.commit()
    try:
        assert TenantStore(dsn).today() == today + dt.timedelta(days=days)  # the store's date did move
        yield
    finally:
        with store.admin() as con:
            con.execute("DROP FUNCTION IF EXISTS fleet.now()")
            con.commit()


def statuses(site) -> list[str]:
    return [e["status"] for e in read_audit(site)]


# -- retention by a clock it can trust ------------------------------------------------------------------------------


def test_a_clock_a_year_fast_deletes_nothing_from_the_store_or_the_lake_and_says_so(fleet, tmp_path):
    store, dsn, today = fleet
    policy, lake, site = DataPolicy("ta", "sk-fast", retention_days=365), tmp_path / "lake", tmp_path / "site"
    first = push(aged("ta", "sk-fast", today, 1, 20, 60), policy, site, TenantStore(dsn), lake, today=today)
    assert (first.new_rows, stored(store, "sk-fast"), lake_rows(lake)) == (3, 3, 3)
    fast = today + dt.timedelta(days=400)
    result = push([], policy, site, TenantStore(dsn), lake, today=fast)
    assert (stored(store, "sk-fast"), lake_rows(lake)) == (3, 3)
    assert result.retention_removed == 0
    (line,) = result.failed  # one warning line (the CLI's exit 1), naming both dates
    assert str(fast) in line and str(today) in line and "deletes nothing" in line and "nothing is sent" in line
    skipped = [e for e in read_audit(site) if e["status"] == "retention"]
    assert {e["destination"] for e in skipped} == {str(lake), TenantStore(dsn).where}
    assert all(e["rows"] == 0 and str(fast) in e["reason"] for e in skipped)


def test_the_stores_cutoff_is_counted_on_the_servers_clock(fleet, tmp_path):
    """A host a day fast (within the day it may be off) deletes by the server's date, not its own."""
    store, dsn, today = fleet
    policy = DataPolicy("ta", "sk-edge", retention_days=30)
    push(aged("ta", "sk-edge", today, 30), policy, tmp_path, TenantStore(dsn), today=today)
    result = push([], policy, tmp_path, TenantStore(dsn), today=today + dt.timedelta(days=1))
    assert stored(store, "sk-edge") == 1  # 30 days old by the server's date: kept
    assert (result.retention_removed, result.failed) == (0, ())


def test_retention_with_a_right_clock_deletes_and_every_push_says_and_logs_how_many(fleet, tmp_path):
    store, dsn, today = fleet
    lake, site = tmp_path / "lake", tmp_path / "site"
    push(aged("ta", "sk-ok", today, 2000, 2000, 1), DataPolicy("ta", "sk-ok", retention_days=36500), site,
         TenantStore(dsn), lake, today=today)
    result = push([], DataPolicy("ta", "sk-ok", retention_days=30), site, TenantStore(dsn), lake, today=today)
    assert (result.failed, stored(store, "sk-ok"), lake_rows(lake)) == ((), 1, 1)
    assert result.retention_removed == 4 and result.to_dict()["retention_removed"] == 4  # 2 from each
    logged = {e["destination"]: e for e in read_audit(site) if e["status"] == "retention"}
    assert {d: e["rows"] for d, e in logged.items()} == {str(lake): 2, TenantStore(dsn).where: 2}
    assert {e["before"] for e in logged.values()} == {str(today - dt.timedelta(days=30))}


def test_a_lake_without_a_store_is_not_emptied_by_a_clock_past_all_its_data(tmp_path):
    lake = tmp_path / "lake"
    rows = [withhold(s, (), KEY) for s in aged("ta", "sk-lake", HOST_TODAY, 1, 20, 60)]
    write_signatures(lake, rows, "earlier")
    policy = DataPolicy("ta", "sk-lake", retention_days=365)
    fast = HOST_TODAY + dt.timedelta(days=400)
    result = push([], policy, tmp_path / "site", None, lake, today=fast)
    assert lake_rows(lake) == 3
    assert result.retention_removed == 0
    (line,) = result.failed
    assert str(fast) in line and str(HOST_TODAY - dt.timedelta(days=1)) in line  # the site's newest signature
    # the right date: what is past the retention goes
    right = push([], DataPolicy("ta", "sk-lake", retention_days=30), tmp_path / "site", None, lake, today=HOST_TODAY)
    assert (lake_rows(lake), right.retention_removed, right.failed) == (2, 1, ())


# -- nothing leaves when the host's and the store's dates disagree ------------------------------------------------


def test_a_store_a_year_slow_lets_no_signature_past_the_retention_leave(fleet, tmp_path):
    """Counted on the store's date, a signature 400 days old by the true date was sent under a 365-day retention."""
    store, dsn, today = fleet
    policy = DataPolicy("ta", "sk-slow", retention_days=365)
    with store_clock_off(fleet, -400):
        result = push(aged("ta", "sk-slow", today, 1, 400), policy, tmp_path, TenantStore(dsn), today=today)
    assert (stored(store, "sk-slow"), result.sent_batches, result.queued, result.held) == (0, 0, 1, ())
    (line,) = result.failed
    assert str(today) in line and str(today - dt.timedelta(days=400)) in line and "nothing is sent" in line
    assert statuses(tmp_path) == ["queued", "retention"]  # the retention's entry says why it did not run
    right = push([], policy, tmp_path, TenantStore(dsn), today=today)  # the store's clock set right
    assert (right.sent_batches, right.queued, right.failed, stored(store, "sk-slow")) == (1, 0, (), 1)
    with store.admin() as con:
        assert con.execute("SELECT min(created_date) FROM fleet.signatures WHERE site_id = 'sk-slow'"
                           ).fetchone()[0] == today - dt.timedelta(days=1)


def test_a_store_a_year_fast_holds_nothing_queued_with_a_right_clock_and_sends_nothing(fleet, tmp_path):
    """Counted on the store's date, every fresh signature stayed at the site and a batch queued with a right clock
    was held (logged held, as if the policy forbade it)."""
    store, dsn, today = fleet
    policy = DataPolicy("ta", "sk-ahead", retention_days=365)
    assert push(aged("ta", "sk-ahead", today, 2), policy, tmp_path, None, today=today).queued == 1
    with store_clock_off(fleet, 400):
        result = push(aged("ta", "sk-ahead", today, 1, 20), policy, tmp_path, TenantStore(dsn), today=today)
    assert (result.batch.rows, result.batch.withheld_rows) == (2, 0)  # exported on this host's date
    assert (result.sent_batches, result.queued, result.held, stored(store, "sk-ahead")) == (0, 2, (), 0)
    (line,) = result.failed
    assert str(today + dt.timedelta(days=400)) in line and "2 batch(es) stay queued" in line
    assert "held" not in statuses(tmp_path)
    right = push([], policy, tmp_path, TenantStore(dsn), today=today)
    assert (right.sent_batches, right.queued, stored(store, "sk-ahead")) == (2, 0, 3)


def test_a_host_a_year_fast_sends_nothing_until_its_clock_is_set(fleet, tmp_path):
    """The batch it queued with its right clock waits (it was held, then sent counted on the store's date)."""
    store, dsn, today = fleet
    policy = DataPolicy("ta", "sk-held", retention_days=365)
    assert push(aged("ta", "sk-held", today, 1), policy, tmp_path, None, today=today).queued == 1
    result = push([], policy, tmp_path, TenantStore(dsn), today=today + dt.timedelta(days=400))
    assert (result.sent_batches, result.held, result.queued, stored(store, "sk-held")) == (0, (), 1, 0)
    assert "held" not in statuses(tmp_path)
    right = push([], policy, tmp_path, TenantStore(dsn), today=today)
    assert (right.sent_batches, right.queued, right.failed, stored(store, "sk-held")) == (1, 0, (), 1)


def test_clocks_a_day_apart_count_what_leaves_on_the_stores_date(fleet, tmp_path):
    """A host a day behind the store (as either is around midnight UTC) built its batch with a signature 31 days old
    by the store's date, which the store's own retention deletes: recounted on the store's date, it stays at the
    site (it was sent, and the store kept a row its audit said was deleted); the queued file is replaced, logged."""
    store, dsn, today = fleet
    policy = DataPolicy("ta", "sk-edge-send", retention_days=30)
    slow = today - dt.timedelta(days=1)
    result = push(aged("ta", "sk-edge-send", slow, 30, 1), policy, tmp_path, TenantStore(dsn), today=slow)
    assert (result.batch.rows, result.batch.withheld_rows, result.sent_batches, result.queued) == (1, 1, 1, 0)
    assert stored(store, "sk-edge-send") == 1
    exports = [e for e in read_audit(tmp_path) if e["status"] == "queued"]
    assert [e["retention_counted_on"] for e in exports] == [str(slow), str(today)]
    assert "recounted on the store's date" in exports[1]["reason"]


def test_a_host_a_day_ahead_holds_no_batch_queued_with_a_right_clock(fleet, tmp_path):
    """A batch queued with a right clock holds a signature 30 days old by the store's date; a host a day ahead
    (31 by its date) counts it on the store's and sends it, not held."""
    store, dsn, today = fleet
    policy = DataPolicy("ta", "sk-day-ahead", retention_days=30)
    push(aged("ta", "sk-day-ahead", today, 30, 1), policy, tmp_path, None, today=today)  # no store: queued
    result = push([], policy, tmp_path, TenantStore(dsn), today=today + dt.timedelta(days=1))
    assert (result.sent_batches, result.held, result.queued) == (1, (), 0)
    assert stored(store, "sk-day-ahead") == 2


def test_a_push_with_the_store_a_year_off_is_one_warning_line_exit_1(fleet, tmp_path):
    store, dsn, today = fleet
    policy = tmp_path / "policy.yaml"
    policy.write_text("tenant: ta\nsite: sk-cli\nexport: nothing\n")
    with store_clock_off(fleet, 400):
        result = CliRunner().invoke(app, ["fleet", "push", str(tmp_path), "--policy", str(policy), "--site-dir",
                                          str(tmp_path / "site"), "--store", dsn])
    assert result.exit_code == 1, result.output
    (line,) = [x for x in result.stderr.splitlines() if x.startswith("warning:")]
    assert str(dates.utc_today()) in line and str(today + dt.timedelta(days=400)) in line, line
    assert "nothing is sent" in line and "deletes nothing" in line, line


def test_with_no_store_to_ask_the_export_counts_on_this_hosts_date(tmp_path):
    result = push(aged("ta", "sk-alone", HOST_TODAY, 1, 40), DataPolicy("ta", "sk-alone", retention_days=30),
                  tmp_path, None, today=HOST_TODAY)
    assert (result.batch.rows, result.batch.withheld_rows, result.queued) == (1, 1, 1)


def test_an_exports_audit_entry_names_the_date_its_retention_was_counted_on(tmp_path):
    """``when_utc`` is the host's clock at the write; the date the export kept rows by was not logged."""
    counted = HOST_TODAY - dt.timedelta(days=400)
    policy = DataPolicy("ta", "sk-dated", retention_days=30)
    push(aged("ta", "sk-dated", counted, 1), policy, tmp_path, None, today=counted)
    push([], policy, tmp_path, None, today=counted)
    assert [(e["status"], e["retention_counted_on"]) for e in read_audit(tmp_path)] == [
        ("queued", str(counted)), ("nothing", str(counted))]


def test_a_push_reads_this_hosts_clock_through_one_helper(fleet, tmp_path, monkeypatch):
    """push, the export and the audit log take this host's date from ``dates`` (push spelled its own UTC date)."""
    store, dsn, today = fleet
    fast = dt.datetime.now(dt.timezone.utc) + dt.timedelta(days=400)
    monkeypatch.setattr(dates, "utc_now", lambda: fast)
    result = push(aged("ta", "sk-one", today, 1), DataPolicy("ta", "sk-one", retention_days=365), tmp_path,
                  TenantStore(dsn))
    (line,) = result.failed
    assert str(fast.date()) in line and result.new_rows == 0 and result.batch.withheld_rows == 1
    (entry, *_) = read_audit(tmp_path)
    assert entry["retention_counted_on"] == str(fast.date())


def test_a_records_start_is_dated_in_utc_whatever_the_hosts_time_zone(monkeypatch):
    monkeypatch.setenv("TZ", "Etc/GMT-14")  # 14 hours east of UTC: 23:30 UTC is the next day there
    time.tzset()
    try:
        late = dt.datetime(2026, 11, 23, 23, 30, tzinfo=dt.timezone.utc)
        assert dates.utc_day(int(late.timestamp() * 1e9)) == dt.date(2026, 11, 23)
        assert dates.utc_today() == dt.datetime.now(dt.timezone.utc).date()
    finally:
        monkeypatch.undo()
        time.tzset()


# -- a store that never answers -------------------------------------------------------------------------------------

INTERRUPTED = """
import datetime as dt, sys
from pathlib import Path
from cellguard.fleet.policy import DataPolicy
from cellguard.fleet.push import push
from cellguard.fleet.signature import Signature
from cellguard.fleet.store import TenantStore
day = dt.datetime.now(dt.timezone.utc).date().isoformat()
push([Signature("ta", "sk-hang", day, "friction", 0.8, "arm5", "c", {"x": 1.0}, 7, 1, "p", "c", "0")],
     DataPolicy("ta", "sk-hang"), Path(sys.argv[1]),
     TenantStore(f"host=127.0.0.1 port={sys.argv[2]} user=x password=x dbname=x", timeout_s=120))
"""


def test_a_push_interrupted_while_the_store_never_answers_leaves_its_batch_queued_and_logged(tmp_path):
    """The store was asked for its date before the batch was queued: a push stopped while it did not answer left
    no outbox and no audit line."""
    pytest.importorskip("psycopg")
    with socket.socket() as silent:  # takes the connection, never answers
        silent.bind(("127.0.0.1", 0))
        silent.listen(1)
        silent.settimeout(1.0)
        site = tmp_path / "site"
        child = subprocess.Popen([sys.executable, "-c", INTERRUPTED, str(site), str(silent.getsockname()[1])],
                                 stderr=subprocess.PIPE, text=True)
        try:
            while child.poll() is None:
                try:
                    asking, _ = silent.accept()
                    break
                except TimeoutError:
                    continue
            assert child.poll() is None, child.stderr.read()  # the push is waiting on the store
            child.kill()  # as Ctrl-C or a power cut while it waits (libpq's wait need not see a SIGINT at once)
            child.wait(timeout=60)
            asking.close()
        finally:
            child.kill()
            child.wait()
    assert len(list((site / "outbox").glob("*.json"))) == 1
    assert statuses(site) == ["queued"]


# -- the outbox's order ---------------------------------------------------------------------------------------------


def counts(n: int) -> list[Signature]:
    return [sig("ta", "sk-box", HOST_TODAY, n=i) for i in range(n)]


AGGREGATES = DataPolicy("ta", "sk-box", export="aggregates_only", min_group_size=2)


def fast_mtime(path) -> None:
    t = time.time() + 600
    os.utime(path, (t, t))


def test_queued_batches_go_in_the_order_they_were_queued_whatever_their_mtime(tmp_path):
    box = Outbox(tmp_path)
    older, newer = (export_batch(counts(n), AGGREGATES, key=KEY) for n in (5, 7))
    fast_mtime(box.put(older))  # written while the clock was ten minutes fast; NTP then stepped it back
    box.put(newer)
    assert [b for _, b in box.pending()] == [older, newer]


def test_a_batch_queued_by_an_older_cellguard_goes_before_those_with_a_place(tmp_path):
    box = Outbox(tmp_path)
    legacy, later, latest = (export_batch(counts(n), AGGREGATES, key=KEY) for n in (3, 4, 5))
    for i, b in enumerate((legacy, later)):  # two files as older versions wrote them: no place, oldest by mtime
        path = tmp_path / "outbox" / f"{b.batch_id}.json"
        path.parent.mkdir(exist_ok=True)
        path.write_text(json.dumps(b.to_dict()))
        os.utime(path, (time.time() + 600 * (i + 1),) * 2)
    box.put(latest)
    assert [b for _, b in box.pending()] == [legacy, later, latest]


def test_a_queued_file_whose_place_is_not_a_count_is_named_and_kept(tmp_path):
    box = Outbox(tmp_path)
    path = box.put(export_batch(counts(2), AGGREGATES, key=KEY))
    path.write_text(json.dumps({**json.loads(path.read_text()), "queued": "1"}))
    batches, ((bad, why),) = box.read()
    assert (batches, bad) == ([], path) and "batch.queued" in why and box.count() == 1


def test_after_the_clock_steps_back_the_store_keeps_the_newest_count(fleet, tmp_path):
    store, dsn, _ = fleet
    push(counts(5), AGGREGATES, tmp_path, None)  # no store: queued
    fast_mtime(next((tmp_path / "outbox").glob("*.json")))
    result = push(counts(7), AGGREGATES, tmp_path, TenantStore(dsn))
    assert (result.sent_batches, result.queued) == (2, 0)
    with store.admin() as con:
        assert con.execute("SELECT signatures FROM fleet.aggregates WHERE site_id = 'sk-box'").fetchall() == [(7,)]


def test_a_push_whose_own_signatures_carry_the_fast_date_does_not_vouch_for_it(tmp_path):
    """The runs pushed were recorded under the same fast clock, so their signatures carry its date: counted as
    the site's newest, they let a year-fast clock with the store down empty the lake (exit 0, nothing said)."""
    lake = tmp_path / "lake"
    write_signatures(lake, [withhold(s, (), KEY) for s in aged("ta", "sk-own", HOST_TODAY, 1, 20, 60)], "earlier")
    fast = HOST_TODAY + dt.timedelta(days=400)
    result = push([sig("ta", "sk-own", fast, n=9)], DataPolicy("ta", "sk-own", retention_days=365),
                  tmp_path / "site", None, lake, today=fast)
    assert result.retention_removed == 0 and lake_rows(lake) >= 3
    assert any(str(fast) in line for line in result.failed)
