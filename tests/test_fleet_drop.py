"""``FleetStore.drop``: a store made for one run (a benchmark's, a test session's) is dropped at its end, database and
roles, on the real PostgreSQL server; any other name is refused before the server is reached. The fleet benchmark's
store had one fixed name, reset as each run began: a second benchmark (or a CI run beside a developer's) dropped the
first's database mid-run, and the last one's stayed on the server. The benchmark's run stores are the tests' own
machinery (``cellguard.fleet.run_stores``), tagged as a benchmark's: a killed one's are swept by the next benchmark or
test session, and the benchmark no longer imports the tests' helpers (nor pytest with them). SIGTERM or SIGHUP
ends the benchmark through its ``finally`` (exit 143 left its work folder behind)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

psycopg = pytest.importorskip("psycopg", reason="the fleet store tests need psycopg: pip install 'cellguard[fleet]'")

from cellguard.errors import ConfigError  # noqa: E402
from cellguard.fleet.run_stores import RunStores  # noqa: E402
from cellguard.fleet.store import FleetStore, TenantStore  # noqa: E402
from fleet_server import admin_dsn_or_skip, store_name, sweep  # noqa: E402

CLOSED = "host=127.0.0.1 port=1 user=postgres dbname=postgres"  # nothing listens: a refusal must not need the server


def _there(admin: str, name: str) -> list[str]:
    """The databases and roles on the server named ``name`` or starting ``name_``."""
    with psycopg.connect(admin, autocommit=True) as con:
        return [n for (n,) in con.execute("SELECT datname FROM pg_database WHERE datname = %(n)s OR starts_with("
                                          "datname, %(p)s) UNION ALL SELECT rolname FROM pg_roles WHERE rolname = %(n)s"
                                          " OR starts_with(rolname, %(p)s)", {"n": name, "p": name + "_"}).fetchall()]


def _installed(name: str, tenants: tuple[str, ...]) -> tuple[FleetStore, list[str]]:
    store = FleetStore(admin_dsn_or_skip(), store_name(name))
    store.install()
    return store, [store.add_tenant(t) for t in tenants]


def test_drop_removes_the_database_and_every_role_it_made_with_a_tenant_still_connected():
    store, (alpha, _) = _installed("drop", ("t-alpha", "t-beta"))
    assert TenantStore(alpha).run("frequency", scope="own") == []
    held = TenantStore(alpha).connection()  # a tenant session open: ended, not waited for
    try:
        made = _there(store.admin_dsn, store.database)
        assert sorted(store.drop()) == sorted(made) and len(made) == 6  # database, its 3 roles, 2 tenants
        assert _there(store.admin_dsn, store.database) == []
    finally:
        held.close()


def test_a_second_drop_drops_nothing_and_says_so():
    store, _ = _installed("drop2", ("t-alpha",))
    assert store.drop() and store.drop() == []
    assert _there(store.admin_dsn, store.database) == []


def test_drop_leaves_another_store_of_the_same_run_as_it_was():
    """Two benchmarks' stores on one server: one's end does not touch the other's database, roles or rows."""
    gone, _ = _installed("dropa", ("t-alpha",))
    kept, (dsn,) = _installed("dropa_b", ("t-alpha",))  # its name starts with the other's
    before = _there(kept.admin_dsn, kept.database)
    gone.drop()
    assert _there(kept.admin_dsn, kept.database) == before
    assert TenantStore(dsn).run("frequency", scope="own") == []
    kept.drop()


@pytest.mark.parametrize("name", ["cellguard_fleet", "cgbench_fleet", "cg1234567_x", "cg12345678", "cg12345678_",
                                  "xcg12345678_bench"])
def test_drop_refuses_a_store_not_made_for_one_run_before_it_reaches_the_server(name):
    with pytest.raises(ConfigError) as refused:
        FleetStore(CLOSED, name).drop()
    said = str(refused.value)
    assert said.startswith(f"database: {name!r} is not a store made for one run") and "\n" not in said, said


KILLED = """
import os, sys
from cellguard.fleet.run_stores import RunStores
from cellguard.fleet.store import FleetStore

stores = RunStores("benchmark", "cellguard fleet benchmark")
stores.open(sys.argv[1])
store = FleetStore(sys.argv[1], stores.name("bench"))
store.install()
store.add_tenant("t-alpha")
stores.tag_stores()
tag = stores.held().execute("SELECT shobj_description(oid, 'pg_database') FROM pg_database WHERE datname = %s",
                            (store.database,)).fetchone()[0]  # read while it lives: once killed, any run may sweep it
print(stores.run)
print(tag, flush=True)
os._exit(9)  # killed: its store neither dropped nor its lock freed by it
"""


def _killed_benchmark(admin: str) -> str:
    """A benchmark's run, killed after it made its store and a tenant, tagged as a benchmark's; its run's name."""
    done = subprocess.run([sys.executable, "-c", KILLED, admin], capture_output=True, text=True, timeout=120)
    assert done.returncode == 9, done.stderr
    run, tag = done.stdout.splitlines()
    assert tag == f"cellguard benchmark {run}"
    return run


def test_a_killed_benchmarks_store_is_tagged_as_a_benchmarks_and_swept_by_the_next_test_session():
    admin = admin_dsn_or_skip()
    run = _killed_benchmark(admin)
    with psycopg.connect(admin, autocommit=True) as con:
        sweep(con)  # or a run that opened the server meanwhile (another xdist worker's) swept it first
    assert _there(admin, run + "_bench") == []  # its database, its three roles and its tenant's


def test_a_killed_benchmarks_store_is_swept_by_the_next_benchmark_and_that_ones_by_its_close():
    admin = admin_dsn_or_skip()
    run = _killed_benchmark(admin)
    nxt = RunStores("benchmark", "cellguard fleet benchmark")
    try:
        nxt.open(admin)
        assert _there(admin, run + "_bench") == []
        FleetStore(admin, nxt.name("bench")).install()
    finally:
        assert nxt.close() is None
    assert _there(admin, nxt.name("bench")) == []


def test_the_fleet_benchmark_imports_no_pytest():
    root = Path(__file__).parents[1]
    code = "import sys; sys.path.insert(0, 'benchmarks'); import fleet; print(sorted(m for m in sys.modules " \
           "if m.split('.')[0] in ('pytest', '_pytest', 'fleet_server')))"
    done = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "[]", done.stdout + done.stderr


SIGNALLED = """
import argparse, os, signal, sys, tempfile
sys.path.insert(0, 'benchmarks')
import fleet


class Signalled(dict):
    '''The runs, read once the work folder and the store are made: where SIGTERM comes.'''
    def __getitem__(self, key):
        print(os.listdir(tempfile.gettempdir()), flush=True)
        os.kill(os.getpid(), signal.SIGTERM)


from cellguard.ending import ended_by_signals

with ended_by_signals():
    fleet.bench(argparse.Namespace(no_spark=True, rows=10, spark_on_fleet_lake=False), sys.argv[1], Signalled(), 1.0,
                lambda name: None, {}, 0.0, (0.0, 0.0, 0.0))
"""


def test_a_benchmark_ended_by_sigterm_removes_its_work_folder(tmp_path):
    admin = admin_dsn_or_skip()
    root = Path(__file__).parents[1]
    env = {**os.environ, "TMPDIR": str(tmp_path)}
    done = subprocess.run([sys.executable, "-c", SIGNALLED, admin], cwd=root, env=env, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 143, (done.returncode, done.stderr[-2000:])
    assert done.stdout.startswith("['cellguard-fleet-"), done.stdout  # it was there when the signal came
    assert list(tmp_path.iterdir()) == []  # removed by its finally, which drops its store too
