"""The lake gets what the store took, decided at the store's COMMIT: a batch's lake files are staged before it and
made visible only after it. A batch refused at the commit (a deferred constraint) leaves nothing in the lake, and
lands once when a later push is taken; a push killed while the server committed leaves its files staged, and the
next push that reaches the store lands what the store holds (under ``export: nothing`` too), nothing more.
Also: `fleet similar --limit 0` is refused before anything is logged; a site dir whose audit log names another site
is refused a push until that site is withdrawn (it stored every finding twice); only the push that made a site key
says so."""

from __future__ import annotations

import datetime as dt
import os
import signal
import subprocess
import sys
import time

import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

psycopg = pytest.importorskip("psycopg", reason="the fleet store tests need psycopg: pip install 'cellguard[fleet]'")

from cellguard.cli import app  # noqa: E402
from cellguard.errors import ConfigError  # noqa: E402
from cellguard.fleet.duckdb_engine import DuckDBEngine  # noqa: E402
from cellguard.fleet.policy import DataPolicy  # noqa: E402
from cellguard.fleet.push import push  # noqa: E402
from cellguard.fleet.signature import Signature  # noqa: E402
from cellguard.fleet.store import FleetStore, TenantStore  # noqa: E402
from fleet_server import admin_dsn_or_skip, store_name  # noqa: E402

TODAY = dt.datetime.now(dt.timezone.utc).date()


def sigs(tenant: str, site: str) -> list[Signature]:
    return [Signature(tenant, site, TODAY.isoformat(), cause, 0.8, "arm5", "arm-pick-place",
                      {"current_rms.elbow": 6.0 + i, "tracking_rms.elbow": 1.2}, 7, 1, "pv-1", "cal-1", "0.1.0")
            for i, cause in enumerate(("friction", "servo"))]


@pytest.fixture()
def fleet(request):
    store = FleetStore(admin_dsn_or_skip(), store_name("cl_" + request.node.originalname.split("_")[2][:6]))
    store.install(reset=True)
    return store, store.add_tenant("tc")


def at_commit(store: FleetStore, body: str) -> None:
    """A deferred trigger on the signatures table running ``body`` at each COMMIT that inserted one."""
    with store.admin() as con:
        con.execute(f"CREATE FUNCTION fleet.at_commit() RETURNS trigger LANGUAGE plpgsql AS $$BEGIN {body}; "
                    f"RETURN NULL; END$$")
        con.execute("CREATE CONSTRAINT TRIGGER at_commit AFTER INSERT ON fleet.signatures DEFERRABLE INITIALLY "
                    "DEFERRED FOR EACH ROW EXECUTE FUNCTION fleet.at_commit()")


def drop_at_commit(store: FleetStore) -> None:
    with store.admin() as con:
        con.execute("DROP TRIGGER at_commit ON fleet.signatures")


def committing(store: FleetStore) -> bool:
    """Whether a session of the store's database is in its COMMIT."""
    with store.admin() as con:
        return bool(con.execute("SELECT count(*) FROM pg_stat_activity WHERE datname = current_database() "
                                "AND state = 'active' AND query = 'COMMIT'").fetchone()[0])


def stored(store: FleetStore) -> int:
    with store.admin() as con:
        return con.execute("SELECT count(*) FROM fleet.signatures").fetchone()[0]


def in_lake(lake) -> tuple[int, int, list[str]]:
    """(signature rows, effect rows, the other files: staged, not yet visible) in the lake."""
    def rows(relation: str) -> int:
        return sum(pq.read_table(p).num_rows for p in lake.glob(f"tenant=tc/{relation}/date=*/*.parquet"))
    others = sorted(p.name for p in lake.rglob("*") if p.is_file() and p.suffix != ".parquet")
    return rows("signatures"), rows("effects"), others


def test_a_batch_refused_at_commit_leaves_nothing_in_the_lake_and_lands_once_later(fleet, tmp_path):
    store, dsn = fleet
    lake, site, policy = tmp_path / "lake", tmp_path / "site", DataPolicy("tc", "s-commit")
    at_commit(store, "RAISE EXCEPTION 'commit-time failure'")
    first = push(sigs("tc", "s-commit"), policy, site, TenantStore(dsn), lake)
    assert (first.sent_batches, first.queued, stored(store)) == (0, 1, 0)
    assert "commit-time failure" in first.failed[0]
    assert in_lake(lake) == (0, 0, [])  # the lake took nothing the store did not
    drop_at_commit(store)
    again = push([], policy, site, TenantStore(dsn), lake)
    assert (again.sent_batches, again.queued, stored(store)) == (1, 0, 2)
    assert in_lake(lake) == (2, 4, [])
    assert sum(r["signatures"] for r in DuckDBEngine(lake).run("frequency", {"k": 1})) == 2


def test_a_push_killed_while_the_store_committed_is_landed_by_the_next_push(fleet, tmp_path):
    store, dsn = fleet
    lake, site = tmp_path / "lake", tmp_path / "site"
    at_commit(store, "PERFORM pg_sleep(1)")  # the commit outlives the push killed during it
    script = ("import sys; from pathlib import Path; from cellguard.fleet.policy import DataPolicy; "
              "from cellguard.fleet.push import push; from cellguard.fleet.store import TenantStore; "
              "from test_fleet_commit_lake import sigs; "
              "push(sigs('tc', 's-kill'), DataPolicy('tc', 's-kill'), Path(sys.argv[1]), TenantStore(sys.argv[2]), "
              "Path(sys.argv[3]))")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([os.path.dirname(__file__), *sys.path])}
    proc = subprocess.Popen([sys.executable, "-c", script, str(site), dsn, str(lake)], env=env)
    try:
        for _ in range(600):
            if committing(store) or proc.poll() is not None:
                break
            time.sleep(0.05)
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait()
    for _ in range(200):
        if stored(store) == 2:
            break
        time.sleep(0.05)
    assert stored(store) == 2 and in_lake(lake)[:2] == (0, 0) and in_lake(lake)[2]
    drop_at_commit(store)
    held = push([], DataPolicy("tc", "s-kill", export="nothing"), site, TenantStore(dsn), lake)
    assert (held.sent_batches, held.queued) == (0, 1)
    assert in_lake(lake) == (2, 4, [])  # what the store holds, once; nothing left staged
    assert sum(r["signatures"] for r in DuckDBEngine(lake, "tc").run("frequency", {"k": 1}, scope="own")) == 2


def test_similar_with_a_limit_out_of_range_writes_nothing(fleet, tmp_path):
    from cellguard.runtime import run_scenario
    from cellguard.scenario import parse_scenario

    store, dsn = fleet
    run_scenario(parse_scenario({"cell": "arm-pick-place", "seed": 11, "acceptance_cycles": 5, "production_cycles": 4,
                                 "faults": [{"kind": "fixture_shift", "at_cycle": 6, "dx_mm": 5.0, "dy_mm": 1.0}]}),
                 tmp_path / "run")
    (tmp_path / "p.yaml").write_text("tenant: tc\nsite: s-sim\nexport: signatures\n")
    for limit in ("0", "-1", "1000001"):
        out = CliRunner().invoke(app, ["fleet", "similar", str(tmp_path / "run"), "--policy", str(tmp_path / "p.yaml"),
                                       "--site-dir", str(tmp_path / "sim"), "--store", dsn, "--limit", limit])
        assert out.exit_code == 2 and "limit" in out.output and len(out.output.strip().splitlines()) == 1
        assert not (tmp_path / "sim").exists()  # no probe logged: none was sent


def test_a_site_renamed_in_the_policy_is_refused_until_the_old_one_is_withdrawn(fleet, tmp_path):
    store, dsn = fleet
    site = tmp_path / "site"
    assert push(sigs("tc", "s-old"), DataPolicy("tc", "s-old"), site, TenantStore(dsn)).new_rows == 2
    with pytest.raises(ConfigError, match=r"site s-old \(tenant tc\) went to .* the policy names site s-new "
                                          r"\(tenant tc\).*fleet withdraw"):
        push(sigs("tc", "s-new"), DataPolicy("tc", "s-new"), site, TenantStore(dsn))
    (tmp_path / "old.yaml").write_text("tenant: tc\nsite: s-old\nexport: signatures\n")
    (tmp_path / "new.yaml").write_text("tenant: tc\nsite: s-new\nexport: signatures\n")
    refused = CliRunner().invoke(app, ["fleet", "push", str(tmp_path / "no-runs"), "--policy",
                                       str(tmp_path / "new.yaml"), "--site-dir", str(site), "--store", dsn])
    assert refused.exit_code == 2 and len(refused.output.strip().splitlines()) == 1 and stored(store) == 2
    withdrawn = CliRunner().invoke(app, ["fleet", "withdraw", "--policy", str(tmp_path / "old.yaml"), "--store", dsn,
                                         "--site-dir", str(site)])
    assert withdrawn.exit_code == 0, withdrawn.output
    assert push(sigs("tc", "s-new"), DataPolicy("tc", "s-new"), site, TenantStore(dsn)).new_rows == 2
    assert stored(store) == 2  # each finding once, under the new site id
    assert [r["sites"] for r in TenantStore(dsn).run("frequency", scope="own")] == [1, 1]


def test_only_the_push_that_made_the_site_key_says_so(tmp_path):
    from cellguard.fleet.site_key import KEY_FILE, make_key

    assert [make_key(tmp_path), make_key(tmp_path)] == [True, False]
    from cellguard.fleet import site_key
    assert site_key._create(tmp_path / KEY_FILE) is False  # lost the race to the link: another push made it
