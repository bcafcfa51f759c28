"""Fleet leftovers: a lake file's footer read once while it is unchanged (and read again once replaced or rewritten),
the one-run stores' lock on the DSN's own database, a trimmed batch named by what was sent."""

from __future__ import annotations

import datetime as dt
import os

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from cellguard.errors import ConfigError
from cellguard.fleet import lake
from cellguard.fleet.lake import EFFECTS, SIGNATURES, check_schema, paths, write_tables


def _one_row(schema: pa.Schema, sid: str = "s1") -> pa.Table:
    cols = {f.name: pa.array([None], f.type) for f in schema}
    cols.update(signature_id=pa.array([sid]), tenant_id=pa.array(["t1"]), created_date=pa.array([dt.date(2026, 1, 5)]))
    return pa.table(cols, schema=schema)


@pytest.fixture
def footers_read(monkeypatch):
    """The footers check_schema reads (the real reader, counted)."""
    read, real = [], pq.read_schema
    monkeypatch.setattr(pq, "read_schema", lambda path, *a, **kw: read.append(path) or real(path, *a, **kw))
    return read


def test_an_unchanged_lake_file_has_its_footer_read_once(tmp_path, footers_read):
    for i in range(3):
        write_tables(tmp_path, _one_row(SIGNATURES, f"s{i}"), EFFECTS.empty_table(), f"b{i}")
    found = paths(tmp_path, "signatures")
    check_schema(found, SIGNATURES)
    check_schema(found, SIGNATURES)
    assert sorted(footers_read) == found


def test_a_lake_file_replaced_by_one_of_another_schema_is_still_refused(tmp_path, footers_read):
    write_tables(tmp_path, _one_row(SIGNATURES), EFFECTS.empty_table(), "b1")
    [found] = paths(tmp_path, "signatures")
    check_schema([found], SIGNATURES)
    other = pa.schema([*SIGNATURES][:-1] + [pa.field("schema_version", pa.string())])
    pq.write_table(_one_row(other), found + ".tmp")
    os.replace(found + ".tmp", found)  # as the lake writes: beside the target, then renamed
    with pytest.raises(ConfigError, match="column schema_version is string"):
        check_schema([found], SIGNATURES)


def test_a_lake_file_rewritten_in_place_with_its_size_and_mtime_kept_is_read_again(tmp_path, footers_read):
    write_tables(tmp_path, _one_row(SIGNATURES), EFFECTS.empty_table(), "b1")
    [found] = paths(tmp_path, "signatures")
    check_schema([found], SIGNATURES)
    before = os.stat(found)
    renamed = pa.schema([f.with_name("cauze") if f.name == "cause" else f for f in SIGNATURES])
    sink = pa.BufferOutputStream()
    pq.write_table(_one_row(renamed), sink, compression="zstd")
    data = sink.getvalue().to_pybytes()
    assert len(data) == before.st_size  # the same length of name: the same size
    with open(found, "r+b") as f:  # same inode, same size, same mtime: only its ctime tells
        f.write(data)
    os.utime(found, ns=(before.st_atime_ns, before.st_mtime_ns))
    if os.stat(found).st_ctime_ns == before.st_ctime_ns:
        pytest.skip("this file system's ctime did not move between two writes")
    with pytest.raises(ConfigError, match="column cauze is not one of the lake's"):
        check_schema([found], SIGNATURES)


def test_the_footer_cache_is_emptied_at_its_bound(tmp_path, monkeypatch, footers_read):
    monkeypatch.setattr(lake, "_AGREED_MAX", 2)
    monkeypatch.setattr(lake, "_AGREED", {})
    for i in range(3):
        write_tables(tmp_path, _one_row(SIGNATURES, f"s{i}"), EFFECTS.empty_table(), f"b{i}")
    check_schema(paths(tmp_path, "signatures"), SIGNATURES)
    assert len(lake._AGREED) <= 2


# -- the one-run stores' lock: on the DSN's own database where the server has no 'postgres' or refuses the role there --


@pytest.fixture
def own_role():
    """A role of this test (no superuser) with a database of its own, and a database it may not connect to; all of
    them this test session's stores (tagged, and dropped at its end should the test not drop them)."""
    psycopg = pytest.importorskip("psycopg", reason="needs psycopg: pip install 'cellguard[fleet]'")
    from psycopg import sql
    from psycopg.conninfo import conninfo_to_dict

    from fleet_server import admin_dsn_or_skip, store_name

    admin = admin_dsn_or_skip()
    role, home, fenced = store_name("f2role"), store_name("f2home"), store_name("f2fenced")
    with psycopg.connect(admin, autocommit=True) as con:
        con.execute(sql.SQL("CREATE ROLE {} LOGIN PASSWORD 'f2-secret'").format(sql.Identifier(role)))
        con.execute(sql.SQL("CREATE DATABASE {} OWNER {}").format(sql.Identifier(home), sql.Identifier(role)))
        con.execute(sql.SQL("CREATE DATABASE {}").format(sql.Identifier(fenced)))
        con.execute(sql.SQL("REVOKE CONNECT ON DATABASE {} FROM PUBLIC").format(sql.Identifier(fenced)))
    port = conninfo_to_dict(admin).get("port", "5432")
    yield admin, f"host=127.0.0.1 port={port} user={role} password=f2-secret dbname={home}", fenced
    with psycopg.connect(admin, autocommit=True) as con:
        for kind, name in (("DATABASE", home), ("DATABASE", fenced), ("ROLE", role)):
            force = sql.SQL(" WITH (FORCE)" if kind == "DATABASE" else "")
            con.execute(sql.SQL("DROP {} IF EXISTS {}{}").format(sql.SQL(kind), sql.Identifier(name), force))


@pytest.fixture
def runs():
    from cellguard.fleet.run_stores import RunStores
    from cellguard.fleet.store import StoreError

    made: list[RunStores] = []

    def new() -> RunStores:
        made.append(RunStores("benchmark", "a test's run"))
        return made[-1]

    yield new
    for run in made:
        try:
            run.close()
        except StoreError:
            pass


@pytest.mark.parametrize("locks_db", ["missing", "fenced"])
def test_a_run_locks_on_its_dsns_database_where_the_server_has_no_locks_database_or_refuses_it(
        own_role, runs, monkeypatch, locks_db):
    from cellguard.fleet import run_stores

    admin, dsn, fenced = own_role
    monkeypatch.setattr(run_stores, "LOCKS_DB", {"missing": "cgf2_no_such_database", "fenced": fenced}[locks_db])
    a = runs()
    a.open(dsn)
    assert a.held().info.dbname == dsn.rsplit("dbname=", 1)[1]


def test_a_lock_that_can_be_taken_nowhere_names_each_database_tried(own_role, runs, monkeypatch):
    from cellguard.fleet import run_stores
    from cellguard.fleet.store import StoreUnavailable

    admin, dsn, fenced = own_role
    monkeypatch.setattr(run_stores, "LOCKS_DB", "cgf2_no_such_database")
    with pytest.raises(StoreUnavailable) as refused:
        runs().open(dsn.rsplit("dbname=", 1)[0] + f"dbname={fenced}")
    said = str(refused.value)
    assert f"/{fenced} unreachable for the run's lock (database 'cgf2_no_such_database': " in said, said
    assert "the DSN's own: " in said, said
    assert 'database "cgf2_no_such_database" does not exist' in said and "\n" not in said, said
    assert f'permission denied for database "{fenced}"' in said and "f2-secret" not in said, said


def test_a_sweep_leaves_alone_a_live_runs_stores_whatever_database_holds_its_lock(own_role, runs, monkeypatch):
    import psycopg
    from psycopg import sql
    from psycopg.conninfo import make_conninfo

    from cellguard.fleet import run_stores

    admin, dsn, fenced = own_role
    with monkeypatch.context() as m:
        m.setattr(run_stores, "LOCKS_DB", fenced)
        a = runs()
        a.open(dsn)  # its lock on its own database
    dead = runs()  # a killed run: its store tagged, its lock free
    with psycopg.connect(admin, autocommit=True) as con:
        for run in (a, dead):
            con.execute(sql.SQL("CREATE DATABASE {}").format(sql.Identifier(run.name("f2live"))))
            con.execute(sql.SQL("COMMENT ON DATABASE {} IS {}").format(sql.Identifier(run.name("f2live")),
                                                                       sql.Literal(run.tag)))
    with psycopg.connect(make_conninfo(admin, dbname="template1"), autocommit=True) as con:
        dropped = runs().sweep(con)  # from a third database: neither the locks' nor a's
    assert dead.name("f2live") in dropped and a.name("f2live") not in dropped, dropped
    with psycopg.connect(admin, autocommit=True) as con:
        con.execute(sql.SQL("DROP DATABASE {}").format(sql.Identifier(a.name("f2live"))))


# -- a queued batch trimmed past the retention: sent under the id of what was sent, logged with the queued one's ------


def test_a_trimmed_batch_is_sent_and_logged_under_the_id_of_what_was_sent(tmp_path):
    pytest.importorskip("psycopg", reason="needs psycopg: pip install 'cellguard[fleet]'")
    from cellguard.fleet.audit import read_audit
    from cellguard.fleet.export import Batch
    from cellguard.fleet.policy import DataPolicy
    from cellguard.fleet.push import push
    from cellguard.fleet.signature import Signature
    from cellguard.fleet.store import FleetStore, TenantStore
    from fleet_server import admin_dsn_or_skip, store_name

    store = FleetStore(admin_dsn_or_skip(), store_name("f2trim"))
    store.install(reset=True)
    dsn = store.add_tenant("ta")
    today, policy = TenantStore(dsn).today(), DataPolicy("ta", "s-trim", retention_days=30)
    sigs = [Signature("ta", "s-trim", (today - dt.timedelta(days=age)).isoformat(), cause, 0.8, "arm5",
                      "arm-pick-place", {"current_rms.elbow": 6.0}) for age, cause in ((32, "friction"), (2, "servo"))]
    queued = push(sigs, policy, tmp_path / "site", None, today=today - dt.timedelta(days=2)).batch  # both kept then
    push([], policy, tmp_path / "site", TenantStore(dsn), lake=tmp_path / "lake")
    sent = read_audit(tmp_path / "site")[-1]
    assert (sent["status"], sent["trimmed_from"], sent["rows"]) == ("sent", queued.batch_id, 1), sent
    what_was_sent = Batch(**{**queued.__dict__, "signatures": queued.signatures[1:], "withheld_rows": 1})
    assert sent["batch_id"] == what_was_sent.batch_id != queued.batch_id
    assert [p.stem for p in (tmp_path / "lake").rglob("signatures/*/*.parquet")] == [sent["batch_id"]]
    store.drop()


def test_a_server_that_does_not_answer_keeps_the_lock_off_any_other_database():
    """Only a server's "no such database" or "permission denied" moves the lock off LOCKS_DB: a timeout or a refused
    connection that moved it would leave it where a sweep looking on LOCKS_DB alone (an older cellguard's) finds
    it free, and drops a live run's stores."""
    from cellguard.fleet.run_stores import RunStores
    from cellguard.fleet.store import StoreUnavailable

    with pytest.raises(StoreUnavailable) as refused:
        RunStores("benchmark", "a test's run").open("host=127.0.0.1 port=1 user=postgres dbname=elsewhere")
    said = str(refused.value)
    assert "unreachable for the run's lock (database 'postgres': " in said and "the DSN's own" not in said and "database 'elsewhere'" not in said, said
