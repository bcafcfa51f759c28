"""The fleet store's PostgreSQL server for tests: its admin DSN (or a skip saying how to start it), and store names
of this test session only, so that two suites on one server (a CI clone and a README check) never reset each other's
passwords or drop each other's databases. What a session makes it drops at its end (conftest.py); what a killed
session left is dropped by the first session a day later."""

from __future__ import annotations

import re
import secrets
import string
import time

import pytest

_DIGITS = string.digits + string.ascii_lowercase
_SESSION_NAME = re.compile(r"cg([0-9a-z]{4})[0-9a-z]{4}_")  # cg, hour, random: no fixed name (cgtest_cli) matches
STALE_HOURS = 24  # a session's stores older than this are a killed session's: no suite runs for a day


def _base36(n: int, width: int) -> str:
    return "".join(_DIGITS[n // 36 ** i % 36] for i in reversed(range(width)))


def _hour() -> int:
    return int(time.time() // 3600)


# this process's stores (each xdist worker has its own): the hour it started, then a random part
SESSION = "cg" + _base36(_hour(), 4) + "".join(secrets.choice(_DIGITS) for _ in range(4))
_server: list[str] = []  # the admin DSN once this process has used the server


def store_name(purpose: str) -> str:
    """A database name for ``purpose`` in this session only (the store takes at most 20 characters: purpose <= 9)."""
    return f"{SESSION}_{purpose}"


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
        _server.append(dsn)
        drop_stores(dsn, stale, best_effort=True)
    return dsn


def stale(name: str) -> bool:
    """Whether ``name`` is of a session that started over STALE_HOURS ago (a fixed or store's own name: never)."""
    found = _SESSION_NAME.match(name)
    return bool(found) and int(found[1], 36) < _hour() - STALE_HOURS


def ours(name: str) -> bool:
    return name.startswith(SESSION + "_")


def drop_stores(dsn: str, which=ours, best_effort: bool = False) -> list[str]:
    """Drop the databases, then the roles, whose names ``which`` picks; return their names. ``best_effort`` (stale
    ones, which another session may be dropping too): what fails is left to a later session."""
    import psycopg
    from psycopg import sql

    dropped = []
    with psycopg.connect(dsn, autocommit=True) as con:
        for kind, listed in (("DATABASE", "SELECT datname FROM pg_database WHERE datname LIKE 'cg%'"),
                             ("ROLE", "SELECT rolname FROM pg_roles WHERE rolname LIKE 'cg%'")):
            for (name,) in con.execute(listed).fetchall():
                if not which(name):
                    continue
                force = sql.SQL(" WITH (FORCE)" if kind == "DATABASE" else "")
                try:
                    con.execute(sql.SQL("DROP {} IF EXISTS {}{}").format(sql.SQL(kind), sql.Identifier(name), force))
                except psycopg.Error:
                    if not best_effort:
                        raise
                    continue
                dropped.append(name)
    return dropped


def drop_session_stores() -> list[str]:
    """At the session's end: drop what it made (nothing, and no connection, when it never used the server)."""
    return drop_stores(_server[0]) if _server else []
