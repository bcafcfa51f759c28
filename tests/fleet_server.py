"""The fleet store's PostgreSQL server for tests: its admin DSN (or a skip saying how to start it), and store names
of this test session only (``cellguard.fleet.run_stores``: the names, the session's lock, the tags, the sweep of a
killed session's or benchmark's stores). conftest.py tags what a session made after each test phase and drops it at
the session's end."""

from __future__ import annotations

import contextlib

import pytest

from cellguard.fleet.run_stores import RunStores, owner, run_key as session_key, tag_of
from cellguard.fleet.store import StoreError

__all__ = ["SESSION", "TAG", "admin_dsn_or_skip", "drop_session_stores", "owner", "session_key", "store_name",
           "sweep", "tag_session_stores"]

RUN = RunStores("test session", "cellguard tests")  # this process's (each xdist worker has its own)
SESSION = RUN.run
TAG = tag_of("test session", "")  # + the session: the comment on each database and role a session made
store_name, sweep = RUN.name, RUN.sweep


def tag_session_stores() -> None:
    """Tag what this session made (conftest, after each test phase). A lost lock fails the next test to use the
    server (``admin_dsn_or_skip``, naming the loss) and is the session's last line (``drop_session_stores``), not
    an error in a pytest hook."""
    with contextlib.suppress(StoreError):
        RUN.tag_stores()


def drop_session_stores() -> str | None:
    """Drop what this session made at its end: the line naming what was left, or that the lock was lost."""
    try:
        return RUN.close()
    except StoreError as exc:
        return str(exc)


def admin_dsn_or_skip() -> str:
    """The admin DSN, this session's lock held on its server (killed runs' stores swept the first time); a skip
    saying how to start the server when there is none, or it cannot be reached."""
    pytest.importorskip("psycopg", reason="needs psycopg: pip install 'cellguard[fleet]'")
    from cellguard.fleet.store import StoreUnavailable, ci_admin_dsn, connect

    dsn = ci_admin_dsn()
    if dsn is None:
        pytest.skip("no fleet store server: run .ci/fleet.sh (or set CELLGUARD_FLEET_ADMIN_DSN)")
    try:
        connect(dsn).close()  # each time: a server gone mid-session skips the tests after
    except StoreUnavailable as exc:
        pytest.skip(f"{exc}: run .ci/fleet.sh")
    RUN.open(dsn)  # a lost lock, or a server other than the session's, fails the test in one line
    return dsn
