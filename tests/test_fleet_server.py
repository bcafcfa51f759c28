"""The tests' store names are this session's own: two suites on one PostgreSQL server (a CI clone and a README check)
never share a database or a tenant role, a session drops what it made at its end, and a killed session's leftovers are
dropped by a session a day later, never another live session's nor a fixed name's."""

from __future__ import annotations

import os
import secrets
import subprocess
import sys
from pathlib import Path

import pytest
from fleet_server import STALE_HOURS, _base36, _hour, admin_dsn_or_skip, drop_stores, stale, store_name
from hypothesis import given
from hypothesis import strategies as st

from cellguard.errors import ConfigError
from cellguard.fleet.store import FleetStore

TESTS = Path(__file__).parent
NAMED = "import fleet_server; print(fleet_server.store_name('cli'))"
CHILD = """
import fleet_server
from cellguard.fleet.store import FleetStore


def test_makes_a_store_and_leaves_it():
    store = FleetStore(fleet_server.admin_dsn_or_skip(), fleet_server.store_name("child"))
    store.install(reset=True)
    store.add_tenant("ta")
    print("SESSION", fleet_server.SESSION)
"""


def child_env() -> dict:
    return {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(TESTS), os.environ.get("PYTHONPATH")]))}


def session_name(hours_ago: int) -> str:
    return "cg" + _base36(_hour() - hours_ago, 4) + _base36(secrets.randbelow(36 ** 4), 4)


def test_two_sessions_name_the_same_store_apart_within_the_stores_limit():
    names = {subprocess.run([sys.executable, "-c", NAMED], env=child_env(), capture_output=True, text=True,
                            check=True).stdout.strip() for _ in range(2)} | {store_name("cli")}
    assert len(names) == 3 and all(n.endswith("_cli") for n in names)
    FleetStore("host=127.0.0.1 dbname=x", store_name("aheadsaid"))  # the longest purpose the tests use: accepted
    with pytest.raises(ConfigError, match="at most 20"):
        FleetStore("host=127.0.0.1 dbname=x", store_name("ten_chars_"))


@pytest.mark.parametrize("name", ["cgtest_cli", "cgtest_cli_t_ta", "cgtest_keywithdrawn", "cgbench_fleet",
                                  "cgbench_fleet_t_t-alpha", "cellguard_fleet", "cellguard_fleet_owner", "cg"])
def test_a_fixed_name_is_never_stale(name):
    assert not stale(name)


@given(hours_ago=st.integers(-100, 10_000),
       purpose=st.from_regex(r"[a-z0-9_]{1,9}(_t_[a-z0-9-]{1,20})?", fullmatch=True))
def test_a_session_name_is_stale_a_day_after_its_session_started(hours_ago, purpose):
    assert stale(f"{session_name(hours_ago)}_{purpose}") == (hours_ago > STALE_HOURS)
    assert not stale(store_name(purpose))


def stores(dsn: str, prefix: str) -> set[str]:
    import psycopg
    with psycopg.connect(dsn) as con:
        return {n for (n,) in con.execute("SELECT datname FROM pg_database WHERE starts_with(datname, %(p)s) UNION "
                                          "SELECT rolname FROM pg_roles WHERE starts_with(rolname, %(p)s)",
                                          {"p": prefix}).fetchall()}


def test_a_session_drops_what_it_made_and_a_killed_sessions_leftovers_only(tmp_path):
    dsn = admin_dsn_or_skip()
    old, live = session_name(STALE_HOURS + 1), session_name(STALE_HOURS - 1)
    for name in (old, live):
        store = FleetStore(dsn, f"{name}_x")
        store.install(reset=True)
        store.add_tenant("ta")
    try:
        (tmp_path / "test_child.py").write_text(CHILD)
        done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-s", "-p", "no:cacheprovider", "-p", "conftest",
                               "test_child.py"], cwd=tmp_path, env=child_env(), capture_output=True, text=True,
                              timeout=300)
        assert done.returncode == 0, done.stdout + done.stderr
        child = done.stdout.split("SESSION ")[1].split()[0]
        assert stores(dsn, child) == set()  # its database and its three roles and its tenant's: dropped at its end
        assert stores(dsn, old) == set()  # a killed session's, a day old: dropped by the next session to start
        assert stores(dsn, live) == {f"{live}_x", f"{live}_x_owner", f"{live}_x_agg", f"{live}_x_app",
                                     f"{live}_x_t_ta"}  # another session's, still running: untouched
    finally:
        drop_stores(dsn, lambda n: n.startswith((old, live)))
