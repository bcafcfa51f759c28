"""The fleet store's PostgreSQL server for tests: its admin DSN, or a skip saying how to start it."""

from __future__ import annotations

import pytest


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
    return dsn
