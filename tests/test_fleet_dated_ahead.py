"""A signature dated after tomorrow never leaves the site with that date: a robot whose clock ran a year fast
recorded a run dated a year ahead, pushed (exit 0) into the store and the lake, where a 30-day retention, counted
from its date, kept it a year and a month. The run is left out with one warning line (exit 1), as a run whose
record is not whole; the export keeps such a signature at the site by the push's date (the store's when it
answers), a queued batch holding one is held, and the store refuses a row dated after its own tomorrow, whoever
sends it (a queued file edited to 2099 was taken).

The fast robot is a real run recorded under libfaketime; the store is the tests' PostgreSQL server
(``.ci/fleet.sh``)."""

from __future__ import annotations

import datetime as dt
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

psycopg = pytest.importorskip("psycopg", reason="the fleet store tests need psycopg: pip install 'cellguard[fleet]'")

from cellguard import dates  # noqa: E402
from cellguard.cli import app  # noqa: E402
from cellguard.errors import RecordError  # noqa: E402
from cellguard.fleet.audit import read_audit  # noqa: E402
from cellguard.fleet.export import Batch, export_batch  # noqa: E402
from cellguard.fleet.from_record import site_signatures  # noqa: E402
from cellguard.fleet.policy import DataPolicy  # noqa: E402
from cellguard.fleet.push import push  # noqa: E402
from cellguard.fleet.signature import Signature  # noqa: E402
from cellguard.fleet.store import FleetStore, StoreError, TenantStore  # noqa: E402
from fleet_server import admin_dsn_or_skip, store_name  # noqa: E402

KEY = b"site-secret-of-the-tests"  # the site key signature ids are keyed with (site_key.py)
FAKETIME = Path("/usr/lib/x86_64-linux-gnu/faketime/libfaketime.so.1")
RUN = """
import sys
from cellguard.runtime import run_scenario
from cellguard.scenario import parse_scenario
run_scenario(parse_scenario({"cell": "arm-pick-place", "seed": 11, "acceptance_cycles": 5, "production_cycles": 4,
                             "faults": [{"kind": "fixture_shift", "at_cycle": 6, "dx_mm": 5.0, "dy_mm": 1.0}]}),
             sys.argv[1])
"""


def sig(day: dt.date, site: str, n: int = 0) -> Signature:
    return Signature("ta", site, day.isoformat(), "friction", 0.8, "arm5", "arm-pick-place",
                     {"current_rms.elbow": 6.0 + n}, 7, 1, "pv-1", "cal-1", "0.1.0")


@pytest.fixture(scope="module")
def fleet():
    store = FleetStore(admin_dsn_or_skip(), store_name("ahead"))
    store.install(reset=True)
    with store.admin() as con:  # the server's date: the tests' "today" wherever the host's differs
        today = con.execute("SELECT (now() AT TIME ZONE 'UTC')::date").fetchone()[0]
    return store, store.add_tenant("ta"), today


def record(folder: Path, **env: str) -> Path:
    subprocess.run([sys.executable, "-c", RUN, str(folder)], env={**os.environ, **env}, check=True, timeout=600)
    return folder


@pytest.fixture(scope="module")
def right(tmp_path_factory):
    """A run recorded on a right clock."""
    return record(tmp_path_factory.mktemp("ahead") / "runs" / "right")


@pytest.fixture(scope="module")
def runs(right):
    """A folder of two runs of the same cell: ``right``, and one by a robot whose clock ran 400 days fast."""
    if not FAKETIME.is_file():
        pytest.skip(f"needs libfaketime ({FAKETIME}): apt-get install faketime")
    record(right.parent / "fast", LD_PRELOAD=str(FAKETIME), FAKETIME="+400d")
    return right.parent


def stored(store, site: str) -> list[str]:
    with store.admin() as con:
        return [d for (d,) in con.execute("SELECT created_date::text FROM fleet.signatures WHERE site_id = %s "
                                               "UNION ALL SELECT month FROM fleet.aggregates WHERE site_id = %s",
                                               (site, site))]


def test_a_run_recorded_by_a_clock_a_year_fast_is_left_out_in_one_warning_line_exit_1(fleet, runs, tmp_path):
    store, dsn, today = fleet
    policy = tmp_path / "policy.yaml"
    policy.write_text("tenant: ta\nsite: s-fast\nexport: signatures\nretention_days: 30\n")
    lake = tmp_path / "lake"
    result = CliRunner().invoke(app, ["fleet", "push", str(runs), "--policy", str(policy), "--site-dir",
                                      str(tmp_path / "site"), "--lake", str(lake), "--store", dsn, "--json"])
    assert result.exit_code == 1, result.output
    (line,) = [x for x in result.stderr.splitlines() if x.startswith("warning:")]
    fast = dates.utc_today() + dt.timedelta(days=400)  # the fast clock's date, give or take midnight
    assert str(runs / "fast") in line and "after tomorrow" in line and "left out" in line, line
    assert any(str(fast + dt.timedelta(days=d)) in line for d in (-1, 0, 1)), line
    out = json.loads(result.stdout)
    assert out["new_rows"] == out["rows"] >= 1  # the run on a right clock went
    days = stored(store, "s-fast")
    assert len(days) == out["rows"] and max(days) <= str(today + dt.timedelta(days=1)), days
    lake_days = {p.name for p in lake.rglob("date=*")}
    assert lake_days and max(lake_days) <= f"date={today + dt.timedelta(days=1)}", lake_days


def test_a_run_that_started_after_this_hosts_tomorrow_is_named_and_left_out(right, monkeypatch):
    """The same check with no libfaketime: a run recorded now, pushed by a host whose clock is a year behind."""
    slow = dates.utc_now() - dt.timedelta(days=400)
    monkeypatch.setattr(dates, "utc_now", lambda: slow)
    skipped: list[str] = []
    assert site_signatures(right, DataPolicy("ta", "s-slow"), skipped=skipped) == []
    (line,) = skipped
    assert str(right) in line and f"after tomorrow ({slow.date() + dt.timedelta(days=1)})" in line, line
    with pytest.raises(RecordError, match="after tomorrow"):  # no list to name it in
        site_signatures(right, DataPolicy("ta", "s-slow"))
    probes = site_signatures(right, DataPolicy("ta", "s-slow"), skipped=skipped, stored=False)
    assert probes and skipped == [line]  # fleet similar's probes, stored nowhere, still go
    monkeypatch.undo()
    assert site_signatures(right, DataPolicy("ta", "s-slow"))  # by a right clock its findings go


def test_the_export_keeps_at_the_site_what_is_dated_after_tomorrow():
    today = dt.date(2026, 11, 27)
    signatures = [sig(today + dt.timedelta(days=d), "s-unit", n) for n, d in enumerate((0, 1, 2, 400, 401))]
    batch = export_batch(signatures, DataPolicy("ta", "s-unit", retention_days=30), today, key=KEY)
    assert [s["created_date"] for s in batch.signatures] == ["2026-11-27", "2026-11-28"]  # a day's leeway
    assert batch.withheld_rows == 3
    counts = export_batch(signatures, DataPolicy("ta", "s-unit", export="aggregates_only", min_group_size=2,
                                                 retention_days=30), today, key=KEY)
    assert [(r["month"], r["signatures"]) for r in counts.aggregates] == [("2026-11", 2)]


def test_a_host_a_day_ahead_of_the_store_sends_nothing_dated_after_the_stores_tomorrow(fleet, tmp_path):
    """Counted on the host's date, a signature dated two days after the store's was within its leeway; the push
    counts on the store's date when it answers, and keeps it at the site."""
    store, dsn, today = fleet
    result = push([sig(today + dt.timedelta(days=2), "s-edge"), sig(today, "s-edge", 1)],
                  DataPolicy("ta", "s-edge", retention_days=30), tmp_path, TenantStore(dsn),
                  today=today + dt.timedelta(days=1))
    assert (result.batch.rows, result.batch.withheld_rows, result.new_rows, result.failed) == (1, 1, 1, ())
    assert stored(store, "s-edge") == [str(today)]


@pytest.mark.parametrize("case", ["queued by a host a year fast", "edited to 2099"])
def test_a_queued_batch_with_a_row_dated_ahead_is_held_at_the_site(fleet, tmp_path, case):
    store, dsn, today = fleet
    policy = DataPolicy("ta", "s-held", retention_days=30)
    fast = today + dt.timedelta(days=400)
    if case == "edited to 2099":
        push([sig(today, "s-held")], policy, tmp_path, None, today=today)  # no store: queued
        (path,) = (tmp_path / "outbox").glob("*.json")
        raw = json.loads(path.read_text())
        raw["signatures"][0]["created_date"] = "2099-01-01"
        del raw["batch_id"]
        path.write_text(json.dumps(raw))
    else:  # the robot's and the site host's clocks a year fast, no store to ask: it was queued on the host's date
        push([sig(fast, "s-held")], policy, tmp_path, None, today=fast)
    result = push([], policy, tmp_path, TenantStore(dsn), today=today)
    assert (result.sent_batches, result.queued, result.failed, stored(store, "s-held")) == (0, 1, (), [])
    (line,) = result.held
    assert "dated after tomorrow" in line and str(today + dt.timedelta(days=1)) in line, line
    assert read_audit(tmp_path)[-1]["status"] == "held"


def test_the_store_refuses_a_row_dated_after_its_tomorrow_whoever_sends_it(fleet):
    store, dsn, today = fleet
    good = export_batch([sig(today + dt.timedelta(days=1), "s-store")], DataPolicy("ta", "s-store"), today,
                        key=KEY)
    row = dict(good.signatures[0], created_date="2099-01-01")
    for bad, named in ((Batch("ta", "s-store", "v", "signatures", (row,), key_id=good.key_id), "created_date 2099"),
                       (Batch("ta", "s-store", "v", "aggregates_only", aggregates=(
                           {"cause": "friction", "robot_model": None, "cell_type": None, "month": "2099-01",
                            "signatures": 9},)), "month 2099-01")):
        with pytest.raises(StoreError, match=named):
            TenantStore(dsn).push(bad)
    assert stored(store, "s-store") == []
    assert TenantStore(dsn).push(good) == (1, 0)  # the store's tomorrow is within a day's leeway
    with store.admin() as con:  # a store installed before the check: brought up to date by install()
        con.execute("DROP TRIGGER not_dated_ahead ON fleet.signatures")
        con.commit()
    store.install()
    with pytest.raises(StoreError, match="created_date 2099"):
        TenantStore(dsn).push(Batch("ta", "s-store", "v", "signatures", (row,), key_id=good.key_id))
