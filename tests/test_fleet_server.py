"""The tests' store names are this session's own: two suites on one PostgreSQL server (a CI clone and a README check)
never share a database or a tenant role, a session drops what it made at its end (and a server gone by then leaves
one warning line, never a failed run), and a killed session's leftovers are dropped by the next session: only what a
test session tagged as its own, and only once that session's advisory lock is free, whatever any clock says."""

from __future__ import annotations

import os
import re
import secrets
import subprocess
import sys
from pathlib import Path

import pytest
from fleet_server import SESSION, TAG, admin_dsn_or_skip, owner, session_key, store_name, sweep
from hypothesis import given
from hypothesis import strategies as st

from cellguard.errors import ConfigError
from cellguard.fleet.store import FleetStore

psycopg = pytest.importorskip("psycopg", reason="the fleet store tests need psycopg: pip install 'cellguard[fleet]'")
from psycopg import sql  # noqa: E402
from psycopg.conninfo import conninfo_to_dict, make_conninfo  # noqa: E402

TESTS = Path(__file__).parent
NAMED = "import fleet_server; print(fleet_server.store_name('cli'))"
CHILD = """
import os
import fleet_server
from cellguard.fleet.store import FleetStore


def test_makes_a_store_and_leaves_it():
    store = FleetStore(fleet_server.admin_dsn_or_skip(), fleet_server.store_name("child"))
    store.install(reset=True)
    store.add_tenant("ta")
    print("SESSION", fleet_server.SESSION)
    if os.environ.get("GONE"):  # the server's socket gone before the session's end (another suite's fleet.sh stop)
        os.remove(os.environ["GONE"])
"""
SESSIONS = st.from_regex(r"cg[0-9a-z]{8}", fullmatch=True)


def run_child(tmp_path: Path, **env: str) -> tuple[subprocess.CompletedProcess, str]:
    """A pytest session of its own that makes a store; its result and its session's name."""
    (tmp_path / "test_child.py").write_text(CHILD)
    path = os.pathsep.join(filter(None, [str(TESTS), os.environ.get("PYTHONPATH")]))
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-s", "-p", "no:cacheprovider", "-p", "conftest",
                           "test_child.py"], cwd=tmp_path, env={**os.environ, "PYTHONPATH": path, **env},
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    return done, done.stdout.split("SESSION ")[1].split()[0]


def test_two_sessions_name_the_same_store_apart_within_the_stores_limit():
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(TESTS), os.environ.get("PYTHONPATH")]))}
    names = {subprocess.run([sys.executable, "-c", NAMED], env=env, capture_output=True, text=True,
                            check=True).stdout.strip() for _ in range(2)} | {store_name("cli")}
    assert len(names) == 3 and all(n.endswith("_cli") for n in names)
    FleetStore("host=127.0.0.1 dbname=x", store_name("aheadsaid"))  # the longest purpose the tests use: accepted
    with pytest.raises(ConfigError, match="at most 20"):
        FleetStore("host=127.0.0.1 dbname=x", store_name("ten_chars_"))


@pytest.mark.parametrize("name", ["cgtest_cli", "cgtest_cli_t_ta", "cgbench_fleet", "cellguard_fleet", "cg",
                                  "cg2024plnt_fleet", "cg2024plnt_fleet_owner"])
@pytest.mark.parametrize("tag", [None, "", "production fleet", "cellguard test session", TAG + "cg2024plnx"])
def test_a_name_no_session_tagged_is_nobodys(name, tag):
    assert owner(name, tag) is None


@given(session=SESSIONS, purpose=st.from_regex(r"[a-z0-9_]{1,9}(_t_[a-z0-9-]{1,20})?", fullmatch=True))
def test_a_tagged_name_is_its_sessions(session, purpose):
    assert owner(f"{session}_{purpose}", TAG + session) == session
    assert owner(f"{session}_{purpose}", TAG + session + " ") is None
    assert owner(f"{session}_{purpose}", None) is None  # untagged: not even this session's own, until tagged


@given(name=st.text(max_size=30), tag=st.one_of(st.none(), st.text(max_size=40), SESSIONS.map(TAG.__add__)))
def test_a_session_is_read_only_from_a_tag_naming_it_on_a_name_it_starts(name, tag):
    session = owner(name, tag)
    assert session is None or (tag == TAG + session and name.startswith(session + "_")
                               and re.fullmatch(r"cg[0-9a-z]{8}", session))


def stores(dsn: str, prefix: str) -> dict[str, str | None]:
    """The databases and roles whose names start with ``prefix``, and their comments."""
    with psycopg.connect(dsn) as con:
        return dict(con.execute("SELECT datname, shobj_description(oid, 'pg_database') FROM pg_database "
                                "WHERE starts_with(datname, %(p)s) UNION SELECT rolname, "
                                "shobj_description(oid, 'pg_authid') FROM pg_roles WHERE starts_with(rolname, %(p)s)",
                                {"p": prefix}).fetchall())


def leftover(con, session: str, tag: str | None) -> set[str]:
    """A database and a role of ``session``'s, each made by one statement (a sweep never sees them half made)."""
    names = {"DATABASE": f"{session}_x", "ROLE": f"{session}_x_app"}
    for kind, name in names.items():
        con.execute(sql.SQL("CREATE {} {}").format(sql.SQL(kind), sql.Identifier(name)))
        if tag:
            con.execute(sql.SQL("COMMENT ON {} {} IS {}").format(sql.SQL(kind), sql.Identifier(name), sql.Literal(tag)))
    return set(names.values())


@pytest.fixture
def live():
    """A store of this (live) session, made in a setup phase: conftest tags it at that phase's end."""
    store = FleetStore(admin_dsn_or_skip(), store_name("live"))
    store.install(reset=True)
    store.add_tenant("ta")
    return store


def test_a_session_drops_what_it_made_and_a_killed_sessions_tagged_leftovers_only(tmp_path, live):
    dsn = admin_dsn_or_skip()
    dead, held, foreign = ("cg" + secrets.token_hex(4), "cg0000" + secrets.token_hex(2),
                           "cg0000" + secrets.token_hex(2))  # 0000: a name that reads as of the hour 0
    with psycopg.connect(dsn, autocommit=True) as con:
        try:
            con.execute("SELECT pg_advisory_lock(%s)", (session_key(held),))  # live before its store is: no sweep
            made = {dead: leftover(con, dead, f"cellguard test session {dead}"),  # between (another worker's) takes it
                    held: leftover(con, held, f"cellguard test session {held}"),  # a session that is live: its lock
                    foreign: leftover(con, foreign, None)}  # a server's own store its admin named so: no tag
            _, child = run_child(tmp_path)
            assert stores(dsn, child) == {}  # its database and its three roles and its tenant's: dropped at its end
            assert stores(dsn, dead) == {}  # a killed session's: dropped by the next session to start
            assert set(stores(dsn, held)) == made[held] and set(stores(dsn, foreign)) == made[foreign]
            assert stores(dsn, store_name("live")) == {  # this session's, tagged, live: untouched
                name: TAG + SESSION for name in (live.database, live.owner, live.agg, live.app, live.tenant_role("ta"))}
        finally:
            for session in (dead, held, foreign):
                for kind, name in (("DATABASE", f"{session}_x"), ("ROLE", f"{session}_x_app")):
                    con.execute(sql.SQL("DROP {} IF EXISTS {}").format(sql.SQL(kind), sql.Identifier(name)))


def test_a_server_gone_at_a_sessions_end_leaves_one_warning_and_its_stores_for_the_next_session(tmp_path):
    dsn = admin_dsn_or_skip()
    host = conninfo_to_dict(dsn).get("host", "")
    if not os.path.isdir(host):
        pytest.skip(f"needs the server's socket folder in the admin DSN, not {host!r}")
    (tmp_path / "run").mkdir()
    (tmp_path / "pg").symlink_to(host)  # the child's way to the server: gone when the child removes it
    done, child = run_child(tmp_path / "run", CELLGUARD_FLEET_ADMIN_DSN=make_conninfo(dsn, host=str(tmp_path / "pg")),
                            GONE=str(tmp_path / "pg"))
    warned = [line for line in (done.stdout + done.stderr).splitlines() if line.startswith("cellguard tests:")]
    assert len(warned) == 1 and f"{child}_* (" in warned[0], done.stdout + done.stderr
    left = {f"{child}_child", f"{child}_child_owner", f"{child}_child_agg", f"{child}_child_app",
            f"{child}_child_t_ta"}
    remaining = stores(dsn, child)  # all of them, unless a session starting meanwhile dropped them already
    assert set(remaining) <= left and set(remaining.values()) <= {TAG + child}  # tagged as the child's while it ran
    with psycopg.connect(dsn, autocommit=True) as con:
        sweep(con)  # the child's lock went with it: the next session drops them
    assert stores(dsn, child) == {}
