"""``RunStores`` on the real PostgreSQL server: a run that lost its lock connection (and its lock with it) hears so at
its next use instead of going on while the next run drops its stores; a sweep finds a run's lock on any database
(advisory locks are per database: ``pg_locks``); and a run stays on the one server it opened."""

from __future__ import annotations

import contextlib

import pytest

psycopg = pytest.importorskip("psycopg", reason="the fleet store tests need psycopg: pip install 'cellguard[fleet]'")

from psycopg.conninfo import make_conninfo  # noqa: E402

from cellguard.fleet.run_stores import RunStores  # noqa: E402
from cellguard.fleet.store import FleetStore, StoreError  # noqa: E402
from fleet_server import admin_dsn_or_skip  # noqa: E402

CLOSED = "host=127.0.0.1 port=1 user=postgres dbname=postgres"  # nothing listens: a refusal must not need the server


@pytest.fixture
def run():
    """A benchmark's run of this test's own (not the session's), closed at the test's end whatever happened."""
    made: list[RunStores] = []

    def new(who: str = "a test's run") -> RunStores:
        made.append(RunStores("benchmark", who))
        return made[-1]

    yield new
    for stores in made:
        with contextlib.suppress(StoreError):
            stores.close()


def _databases(admin: str, run: str) -> list[str]:
    with psycopg.connect(admin, autocommit=True) as con:
        return [n for (n,) in con.execute("SELECT datname FROM pg_database WHERE starts_with(datname, %s) "
                                          "ORDER BY datname", (run + "_",)).fetchall()]


def _opened_with_a_store(stores: RunStores, dsn: str, purpose: str) -> RunStores:
    stores.open(dsn)
    FleetStore(dsn, stores.name(purpose)).install()
    stores.tag_stores()
    return stores


def test_a_lost_lock_is_an_error_at_the_runs_next_use_and_its_end_still_drops_what_it_made(run):
    admin = admin_dsn_or_skip()
    a = _opened_with_a_store(run("A"), admin, "lost")
    with psycopg.connect(admin, autocommit=True) as con:  # a server restart, an idle timeout, a proxy: the same
        con.execute("SELECT pg_terminate_backend(pid) FROM pg_stat_activity WHERE application_name = %s", (a.tag,))
    FleetStore(admin, a.name("late")).install()  # made after the loss: no run would ever tag or drop it
    with pytest.raises(StoreError) as lost:
        a.tag_stores()
    said = str(lost.value)
    assert f"the lock of run {a.run} was lost (terminating connection due to administrator command)" in said, said
    with pytest.raises(StoreError, match="was lost"):
        a.open(admin)
    with pytest.raises(StoreError) as ended:
        a.close()
    assert str(ended.value).startswith("A: fleet store ") and "was lost" in str(ended.value), ended.value
    assert _databases(admin, a.run) == []  # both stores dropped at its end all the same
    assert a.close() is None  # closed: nothing more to say


def test_the_lock_connection_has_tcp_keepalives(run):
    a = run()
    a.open(admin_dsn_or_skip())
    params = a.held().info.get_parameters()
    assert params.get("keepalives") == "1" and int(params.get("keepalives_idle", 0)) > 0, params


def test_a_run_whose_dsn_names_another_database_leaves_a_live_runs_stores_alone(run):
    admin = admin_dsn_or_skip()
    a = _opened_with_a_store(run("A"), make_conninfo(admin, dbname="postgres"), "live")
    b = run("B")
    b.open(make_conninfo(admin, dbname="template1"))  # its sweep: a's lock is held, wherever b's DSN points
    assert _databases(admin, a.run) == [a.name("live")]
    assert b.held().info.dbname == a.held().info.dbname == "postgres"


def test_a_sweep_on_another_database_leaves_a_live_runs_stores_alone(run):
    admin = admin_dsn_or_skip()
    a = _opened_with_a_store(run("A"), admin, "live")
    with psycopg.connect(make_conninfo(admin, dbname="template1"), autocommit=True) as con:
        assert run("B").sweep(con) == []  # a's lock is on 'postgres': found there through pg_locks
    assert _databases(admin, a.run) == [a.name("live")]


def test_an_open_run_refuses_another_server_before_it_reaches_it(run):
    a = run()
    a.open(admin_dsn_or_skip())
    with pytest.raises(StoreError) as refused:
        a.open(CLOSED)
    said = str(refused.value)
    assert said.startswith(f"fleet store 127.0.0.1:1/postgres: run {a.run} holds its lock on ") and "\n" not in said
    a.open(" ".join(reversed(admin_dsn_or_skip().split())))  # the same server, its parameters in another order
