"""The lake gets what the store took, decided at the store's COMMIT: a batch's lake files are staged before it and
made visible only after it. A batch refused at the commit (a deferred constraint) leaves nothing in the lake, and
lands once when a later push is taken; a push killed while the server committed leaves its files staged, and the
next push that reaches the store lands what the store holds (under ``export: nothing`` too), nothing more; so does
a batch half published (its effects moved, its signatures not). A partition file that cannot be read leaves the
batch queued and the store as it was; a reconcile never takes a file a live push is writing; staged files a lake
without locks cannot reconcile are named; a withdrawal takes the site out of staged files too, and one made with
another tenant's store credentials is refused and clears nothing.
Also: `fleet similar --limit 0` is refused before anything is logged; a site dir whose audit log names another site
is refused a push until that site is withdrawn (it stored every finding twice); only the push that made a site key
says so."""

from __future__ import annotations

import datetime as dt
import errno
import fcntl
import os
import signal
import subprocess
import sys
import threading
import time

import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

psycopg = pytest.importorskip("psycopg", reason="the fleet store tests need psycopg: pip install 'cellguard[fleet]'")

from cellguard.cli import app  # noqa: E402
from cellguard.errors import ConfigError  # noqa: E402
from cellguard.fleet.audit import append_withdrawal  # noqa: E402
from cellguard.fleet.duckdb_engine import DuckDBEngine  # noqa: E402
from cellguard.fleet.lake import STAGED, effects_of, forget  # noqa: E402
from cellguard.fleet.landing import reconcile, stage_signatures  # noqa: E402
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
    site, results, start = tmp_path / "site", [], threading.Barrier(2)

    def first_push() -> None:
        start.wait()
        results.append(push(sigs("tc", "s-key"), DataPolicy("tc", "s-key"), site, None))

    threads = [threading.Thread(target=first_push) for _ in range(2)]
    [t.start() for t in threads]
    [t.join() for t in threads]
    assert sorted(r.new_key is not None for r in results) == [False, True]


def test_withdraw_under_another_tenants_store_is_refused_and_clears_nothing(fleet, tmp_path):
    store, dsn = fleet
    other, site = store.add_tenant("td"), tmp_path / "site"
    assert push(sigs("tc", "s-t"), DataPolicy("tc", "s-t"), site, TenantStore(dsn)).new_rows == 2
    (tmp_path / "old.yaml").write_text("tenant: tc\nsite: s-t\nexport: signatures\n")
    out = CliRunner().invoke(app, ["fleet", "withdraw", "--policy", str(tmp_path / "old.yaml"), "--store", other,
                                   "--site-dir", str(site)])
    assert out.exit_code == 2 and len(out.output.strip().splitlines()) == 1, out.output
    assert "tenant td's, the policy's tenant is tc: nothing withdrawn" in out.output and stored(store) == 2
    assert "withdrawn" not in (site / "audit.jsonl").read_text()
    append_withdrawal(site, DataPolicy("tc", "s-t"), 0, TenantStore(dsn).where)  # as 51f2774 logged it: unchecked
    with pytest.raises(ConfigError, match="store credentials of tenant tc"):
        push(sigs("td", "s-t"), DataPolicy("td", "s-t"), site, TenantStore(other))
    assert stored(store) == 2


def test_a_damaged_partition_file_leaves_the_batch_queued_and_the_store_untouched(fleet, tmp_path):
    store, dsn = fleet
    lake, site, policy = tmp_path / "lake", tmp_path / "site", DataPolicy("tc", "s-dmg")
    assert push(sigs("tc", "s-dmg")[:1], policy, site, TenantStore(dsn), lake).new_rows == 1
    damage_column(next(lake.glob("tenant=tc/signatures/date=*/*.parquet")), "cause")
    again = push(sigs("tc", "s-dmg"), policy, site, TenantStore(dsn), lake)
    assert (again.sent_batches, again.queued, stored(store)) == (0, 1, 1)
    assert "cannot read it" in again.failed[0] and again.failed[0].endswith("it stays queued")
    assert not list(lake.rglob(f"*{STAGED}"))  # nothing staged


def damage_column(path, column: str) -> None:
    """Flip the last bytes of ``column``'s data page: the file's other columns still read."""
    meta = pq.ParquetFile(path).metadata.row_group(0)
    chunk = next(meta.column(i) for i in range(meta.num_columns) if meta.column(i).path_in_schema == column)
    data = bytearray(path.read_bytes())
    end = chunk.data_page_offset + chunk.total_compressed_size
    data[end - 6:end] = bytes(b ^ 0xFF for b in data[end - 6:end])
    path.write_bytes(bytes(data))
    pq.read_table(path, columns=["signature_id"])
    with pytest.raises(OSError):
        pq.read_table(path)


def test_a_half_published_batch_is_landed_by_the_next_push(fleet, tmp_path, monkeypatch):
    store, dsn = fleet
    lake, site, policy = tmp_path / "lake", tmp_path / "site", DataPolicy("tc", "s-half")
    real = os.replace

    def signatures_rename_fails(src, dst):  # the effects moved, the signatures not (or the push killed between)
        if str(src).endswith(STAGED) and "/signatures/" in str(src):
            raise OSError(errno.EIO, "Input/output error")
        return real(src, dst)

    monkeypatch.setattr(os, "replace", signatures_rename_fails)
    first = push(sigs("tc", "s-half"), policy, site, TenantStore(dsn), lake)
    monkeypatch.undo()
    assert (first.sent_batches, first.queued, stored(store)) == (1, 0, 2)
    push([], policy, site, TenantStore(dsn), lake)
    assert in_lake(lake) == (2, 4, [])  # what the store holds, effects too
    assert "1 of its lake file(s) stay staged" in first.failed[0]


def test_a_reconcile_between_a_staged_files_creation_and_its_lock_leaves_it(tmp_path, monkeypatch):
    lake, real, seen = tmp_path / "lake", fcntl.flock, []

    def reconcile_first(fd, op):  # another push's reconcile runs just before this push takes its lock
        if not op & fcntl.LOCK_NB and not seen:
            seen.append(reconcile(lake, "tc", lambda ids: {}))
        return real(fd, op)

    monkeypatch.setattr(fcntl, "flock", reconcile_first)
    landing = stage_signatures(lake, ROWS, "b" * 32)
    assert len(seen) == 1 and landing.publish() == 1
    assert in_lake(lake) == (1, 1, [])


def test_staged_files_a_lake_without_locks_cannot_reconcile_are_named(fleet, tmp_path, monkeypatch):
    _, dsn = fleet

    def no_locks(fd, op):
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(fcntl, "flock", no_locks)
    lake = tmp_path / "lake"
    stage_signatures(lake, ROWS, "b" * 32).release()  # as a push killed after its commit left it
    staged = next(lake.glob(f"tenant=tc/signatures/date=*/*{STAGED}"))
    held = push([], DataPolicy("tc", "s-lock", export="nothing"), tmp_path / "site", TenantStore(dsn), lake)
    assert [f for f in held.failed if str(staged) in f and "no file locks" in f]


def test_withdrawing_from_the_lake_takes_the_site_out_of_staged_files_too(tmp_path):
    lake = tmp_path / "lake"
    other = {**ROWS[0], "signature_id": "c" * 32, "site_id": "s-other"}
    stage_signatures(lake, [*ROWS, other], "b" * 32).release()  # as a push killed after its commit left it
    assert forget(lake, "tc", "s-w") == 1
    staged = next(lake.glob(f"tenant=tc/signatures/date=*/*{STAGED}"))
    assert pq.read_table(staged).column("site_id").to_pylist() == ["s-other"]
    assert pq.read_table(effects_of(staged)).column("signature_id").to_pylist() == ["c" * 32]


ROWS = [{"signature_id": "a" * 32, "tenant_id": "tc", "site_id": "s-w", "created_date": TODAY.isoformat(),
         "cause": "friction", "schema_version": 1, "effects": {"current_rms.elbow": 1.0}}]
