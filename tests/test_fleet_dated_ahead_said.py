"""What the push keeps back as dated after tomorrow, it says, in one line naming the dates, the day they are after
and by whose clock. A site host a day ahead of the store let a record dated its own tomorrow past its check (the
store's day after tomorrow); the push, counting on the store's date, kept its signature at the site and said so
only in the "kept at the site" count (exit 0), while a record dated further ahead got a warning line (exit 1).

The record is a real run by a robot whose clock ran two days fast (libfaketime), pushed by a host one day fast to
the tests' PostgreSQL server (``.ci/fleet.sh``)."""

from __future__ import annotations

import datetime as dt
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cellguard import dates
from cellguard.cli import app
from cellguard.fleet.policy import DataPolicy
from cellguard.fleet.push import push
from cellguard.fleet.signature import Signature

FAKETIME = Path("/usr/lib/x86_64-linux-gnu/faketime/libfaketime.so.1")
RUN = """
import sys
from cellguard.runtime import run_scenario
from cellguard.scenario import parse_scenario
run_scenario(parse_scenario({"cell": "arm-pick-place", "seed": 11, "acceptance_cycles": 5, "production_cycles": 4,
                             "faults": [{"kind": "fixture_shift", "at_cycle": 6, "dx_mm": 5.0, "dy_mm": 1.0}]}),
             sys.argv[1])
"""


def sig(day: dt.date, n: int = 0) -> Signature:
    return Signature("ta", "s1", day.isoformat(), "friction", 0.8, "arm5", "arm-pick-place",
                     {"current_rms.elbow": 6.0 + n}, 7, 1)


@pytest.fixture(scope="module")
def fleet():
    from fleet_server import admin_dsn_or_skip, store_name

    from cellguard.fleet.store import FleetStore, TenantStore

    store = FleetStore(admin_dsn_or_skip(), store_name("aheadsaid"))
    store.install(reset=True)
    dsn = store.add_tenant("ta")
    return dsn, TenantStore(dsn).today()


def test_a_host_a_day_ahead_of_the_store_says_what_it_kept_back(fleet, tmp_path):
    from cellguard.fleet.store import TenantStore

    dsn, today = fleet
    ahead = today + dt.timedelta(days=2)  # the host's tomorrow: past its check, after the store's tomorrow
    result = push([sig(ahead), sig(today, 1)], DataPolicy("ta", "s1"), tmp_path, TenantStore(dsn),
                  today=today + dt.timedelta(days=1))
    assert (result.batch.rows, result.batch.withheld_rows, result.new_rows) == (1, 1, 1)
    assert result.dated_ahead == (f"1 signature(s) dated {ahead} kept at the site: after tomorrow "
                                  f"({today + dt.timedelta(days=1)}) by the fleet store's UTC date (the clock that "
                                  f"recorded them ran ahead, or the fleet store's clock is behind): the retention "
                                  f"counts from that date, so it would keep them past it")
    assert json.loads(json.dumps(result.to_dict()))["dated_ahead"] == result.dated_ahead


def test_with_no_store_the_line_names_this_hosts_date_and_the_span(tmp_path):
    today = dt.date(2026, 3, 1)
    signatures = [sig(today + dt.timedelta(days=d), d) for d in (0, 5, 2)]
    result = push(signatures, DataPolicy("ta", "s1", export="aggregates_only", min_group_size=2), tmp_path, None,
                  today=today)
    assert result.dated_ahead.startswith("2 signature(s) dated 2026-03-03 to 2026-03-06 kept at the site: after "
                                         "tomorrow (2026-03-02) by this host's UTC date"), result.dated_ahead
    assert push(signatures, DataPolicy("ta", "s1", export="nothing"), tmp_path, None,
                today=today).dated_ahead is None  # the policy keeps every one: nothing to say
    assert push(signatures[:1], DataPolicy("ta", "s1"), tmp_path, None, today=today).dated_ahead is None


def test_cli_push_from_a_host_a_day_ahead_warns_in_one_line_exit_1(fleet, tmp_path, monkeypatch):
    if not FAKETIME.is_file():
        pytest.skip(f"needs libfaketime ({FAKETIME}): apt-get install faketime")
    dsn, today = fleet
    run = tmp_path / "runs" / "fast"
    subprocess.run([sys.executable, "-c", RUN, str(run)], check=True, timeout=600,
                   env={**os.environ, "LD_PRELOAD": str(FAKETIME), "FAKETIME": "+2d"})
    host = dates.utc_now() + dt.timedelta(days=1)
    monkeypatch.setattr(dates, "utc_now", lambda: host)
    policy = tmp_path / "p.yaml"
    policy.write_text("tenant: ta\nsite: s-cli\nexport: signatures\n")
    result = CliRunner().invoke(app, ["fleet", "push", str(run.parent), "--policy", str(policy), "--store", dsn,
                                      "--site-dir", str(tmp_path / "site"), "--json"])
    assert result.exit_code == 1, result.output
    out = json.loads(result.stdout)
    assert out["rows"] == 0 and out["withheld_rows"] >= 1
    (line,) = [x for x in result.stderr.splitlines() if x.startswith("warning:")]
    assert line == f"warning: {out['dated_ahead']}" and f"signature(s) dated {today + dt.timedelta(days=2)}" in line
    assert "by the fleet store's UTC date" in line, line
