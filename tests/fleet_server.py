"""The fleet store's PostgreSQL server for tests: its admin DSN (or a skip saying how to start it), and store names
of this test session only, so that two suites on one server (a CI clone and a README check) never reset each other's
passwords or drop each other's databases. What a session makes it tags as its own (COMMENT, conftest.py after each
test phase) and drops at its end; a killed session's tagged stores are dropped by the next session to use the server.
A session is live while it holds its advisory lock on the server (from before its first store to after its last is
dropped): no clock, neither the host's nor a name's hour, decides, and a name nobody tagged is never dropped."""

from __future__ import annotations

import re
import secrets
import string

import pytest

from cellguard.fleet.queries import first_line

_DIGITS = string.digits + string.ascii_lowercase
TAG = "cellguard test session "  # + the session: the comment on each database and role a session made
_TAGGED = re.compile(re.escape(TAG) + r"(cg[0-9a-z]{8})")
# this process's stores (each xdist worker has its own): cg and 8 random base-36 characters, the lock's key
SESSION = "cg" + "".join(secrets.choice(_DIGITS) for _ in range(8))
_STORES = ("SELECT * FROM (SELECT 'DATABASE' AS kind, datname AS name, shobj_description(oid, 'pg_database') AS tag "
           "FROM pg_database UNION ALL SELECT 'ROLE', rolname, shobj_description(oid, 'pg_authid') FROM pg_roles) s ")
_server: dict = {}  # once this process has used the server: its admin DSN, and the connection holding the lock


def store_name(purpose: str) -> str:
    """A database name for ``purpose`` in this session only (the store takes at most 20 characters: purpose <= 9)."""
    return f"{SESSION}_{purpose}"


def session_key(session: str) -> int:
    """The advisory lock ``session`` holds for its life: its 8 base-36 characters read as one number (no two alike)."""
    return int(session[2:], 36)


def owner(name: str, tag: str | None) -> str | None:
    """The test session a database or role is of: the one its comment ``tag`` names, when the name is that session's;
    None for anything else (a server's own store, however its name reads)."""
    found = _TAGGED.fullmatch(tag or "")
    return found[1] if found and name.startswith(found[1] + "_") else None


def admin_dsn_or_skip() -> str:
    psycopg = pytest.importorskip("psycopg", reason="needs psycopg: pip install 'cellguard[fleet]'")
    from cellguard.fleet.store import ci_admin_dsn

    dsn = ci_admin_dsn()
    if dsn is None:
        pytest.skip("no fleet store server: run .ci/fleet.sh (or set CELLGUARD_FLEET_ADMIN_DSN)")
    try:
        psycopg.connect(dsn, connect_timeout=3).close()
    except psycopg.OperationalError as exc:
        pytest.skip(f"fleet store server not reachable ({str(exc).strip().splitlines()[-1]}): run .ci/fleet.sh")
    if not _server:
        lock = psycopg.connect(dsn, autocommit=True, application_name=f"cellguard tests {SESSION}")
        if not lock.execute("SELECT pg_try_advisory_lock(%s)", (session_key(SESSION),)).fetchone()[0]:
            raise RuntimeError(f"the advisory lock of test session {SESSION} is held by another session")
        _server.update(dsn=dsn, lock=lock)
        sweep(lock)
    return dsn


def _drop(con, stores) -> tuple[list[str], list[str]]:
    """Drop ``stores`` ((kind, name), databases first), each best-effort: what fails is left, and the rest still
    dropped. Return the names dropped, and a line for each left."""
    import psycopg
    from psycopg import sql

    dropped, left = [], []
    for kind, name in sorted(stores):  # DATABASE before ROLE: a role owning objects in its database goes after it
        force = sql.SQL(" WITH (FORCE)" if kind == "DATABASE" else "")
        try:
            con.execute(sql.SQL("DROP {} IF EXISTS {}{}").format(sql.SQL(kind), sql.Identifier(name), force))
            dropped.append(name)
        except psycopg.Error as exc:
            left.append(f"{name} ({first_line(exc)})")
    return dropped, left


def sweep(con) -> list[str]:
    """Drop the tagged stores of every other session whose lock is free (a killed one), holding that lock meanwhile
    so that no other session sweeps them at once; return the names dropped."""
    sessions: dict[str, list[tuple[str, str]]] = {}
    for kind, name, tag in con.execute(_STORES).fetchall():
        if owner(name, tag) not in (None, SESSION):
            sessions.setdefault(owner(name, tag), []).append((kind, name))
    dropped = []
    for session, stores in sessions.items():
        if con.execute("SELECT pg_try_advisory_lock(%s)", (session_key(session),)).fetchone()[0]:
            try:
                dropped += _drop(con, stores)[0]
            finally:
                con.execute("SELECT pg_advisory_unlock(%s)", (session_key(session),))
    return dropped


def _own(con) -> list[tuple[str, str, str | None]]:
    return con.execute(_STORES + "WHERE starts_with(name, %s)", (SESSION + "_",)).fetchall()


def tag_session_stores() -> None:
    """Tag what this session has made so far as its own, so that should it be killed the next session drops it.
    Best-effort: on a lost connection nothing is tagged (the session's end still drops what it made)."""
    import psycopg
    from psycopg import sql

    con = _server.get("lock")
    if con is None or con.broken:
        return
    try:
        for kind, name, tag in _own(con):
            if tag != TAG + SESSION:
                con.execute(sql.SQL("COMMENT ON {} {} IS {}").format(sql.SQL(kind), sql.Identifier(name),
                                                                     sql.Literal(TAG + SESSION)))
    except psycopg.Error:
        pass  # the server gone, or a store dropped meanwhile: the next phase's pass or the session's end sees to it


def drop_session_stores() -> str | None:
    """At the session's end: drop what it made (nothing, and no connection, when it never used the server), then
    free its lock. Never fails the session: return one warning line naming what was left (a server gone, another
    suite's ``.ci/fleet.sh stop``), which stays tagged for the next session to drop, or None."""
    if not _server:
        return None
    import psycopg

    from cellguard.fleet.store import _where

    tag_session_stores()
    dsn = _server["dsn"]
    try:
        with psycopg.connect(dsn, autocommit=True, connect_timeout=3) as con:
            left = _drop(con, [(kind, name) for kind, name, _ in _own(con)])[1]
    except psycopg.Error as exc:
        left = [f"{SESSION}_* ({first_line(exc)})"]
    finally:
        _server.pop("lock").close()
        _server.clear()
    return f"cellguard tests: fleet stores left on {_where(dsn)} for the next session to drop: {', '.join(left)}" \
        if left else None
