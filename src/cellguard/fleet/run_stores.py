"""Fleet stores made for one run (a test session, a benchmark) on a shared PostgreSQL server, dropped at its end.

Two runs on one server (a CI clone's tests and a developer's benchmark) must never reset each other's passwords or
drop each other's databases: a run's stores are named ``cg`` + 8 random base-36 characters (the run) + ``_purpose``
(``store.RUN_STORE``, the only names ``FleetStore.drop`` takes). What a run makes it tags as its own (a COMMENT naming
the run and its kind) and drops at its end; a killed run's tagged stores are dropped by the next run to open the
server. A run is live while it holds its advisory lock (the run's characters read as one number) from before its
first store to after its last is dropped: no clock decides, and a name nobody tagged is never dropped. A run takes its
lock on ``LOCKS_DB`` whatever database its DSN names, where every run looks for it, or, on a server without that
database or that refuses the DSN's role there, on the DSN's own; a sweep finds a lock held on any database
(``pg_locks``). A run whose lock connection is lost has lost its lock with it, and says so at its next use
(``RunStores.held``).
"""

from __future__ import annotations

import re
import secrets
import string

from cellguard.errors import ConfigError
from cellguard.fleet.queries import first_line
from cellguard.fleet.store import StoreError, StoreUnavailable, _psycopg, _reason, _where, check_dsn

_DIGITS = string.digits + string.ascii_lowercase
KINDS = ("test session", "benchmark")  # what a run is, as its tag says: ``tag_of``
_TAGGED = re.compile(r"cellguard (?:" + "|".join(KINDS) + r") (cg[0-9a-z]{8})")
LOCKS_DB = "postgres"  # the database a run's lock is on where the server lets it (older runs sweep from there only)
# a dead server or network under the lock connection is found in about a minute, not at the next use hours later
_KEEPALIVES = dict(keepalives=1, keepalives_idle=30, keepalives_interval=10, keepalives_count=3)
_STORES = ("SELECT * FROM (SELECT 'DATABASE' AS kind, datname AS name, shobj_description(oid, 'pg_database') AS tag "
           "FROM pg_database UNION ALL SELECT 'ROLE', rolname, shobj_description(oid, 'pg_authid') FROM pg_roles) s ")
# another session's hold on a run's lock, on any database (an advisory lock on a bigint: its halves, objsubid 1)
# the server's answers that move a run's lock off ``LOCKS_DB`` (libpq gives no SQLSTATE for a refused connection)
_NO_LOCKS_DB = re.compile(r'database "[^"]*" does not exist|permission denied for database')
_HELD_ELSEWHERE = ("SELECT EXISTS (SELECT FROM pg_locks WHERE locktype = 'advisory' AND objsubid = 1 AND granted "
                   "AND (classid::bigint << 32 | objid::bigint) = %s AND pid IS DISTINCT FROM pg_backend_pid())")


def tag_of(kind: str, run: str) -> str:
    """The comment on each database and role ``run`` (a ``kind`` of run) made."""
    return f"cellguard {kind} {run}"


def run_key(run: str) -> int:
    """The advisory lock ``run`` holds for its life: its 8 base-36 characters read as one number (no two alike)."""
    return int(run[2:], 36)


def owner(name: str, tag: str | None) -> str | None:
    """The run a database or role is of: the one its comment ``tag`` names, when the name is that run's; None for
    anything else (a server's own store, however its name reads)."""
    found = _TAGGED.fullmatch(tag or "")
    return found[1] if found and name.startswith(found[1] + "_") else None


def _drop(con, stores) -> tuple[list[str], list[str]]:
    """Drop ``stores`` ((kind, name), databases first), each best-effort: what fails is left, and the rest still
    dropped. Return the names dropped, and a line for each left."""
    psycopg = _psycopg()
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


class RunStores:
    """One run's stores on the server at ``open``'s admin DSN; ``who`` starts the line ``close`` may return."""

    def __init__(self, kind: str, who: str):
        if kind not in KINDS:
            raise ConfigError(f"run kind: {kind!r}; expected one of {', '.join(KINDS)}")
        self.run = "cg" + "".join(secrets.choice(_DIGITS) for _ in range(8))
        self.kind, self.who, self.tag = kind, who, tag_of(kind, self.run)
        self.dsn: str | None = None
        self._lock = None  # the admin connection holding the run's advisory lock, once opened
        self._loss = ""  # why the lock connection was lost, once it was

    def name(self, purpose: str) -> str:
        """A database name for ``purpose`` in this run only (a store takes at most 20 characters: purpose <= 9)."""
        return f"{self.run}_{purpose}"

    def open(self, dsn: str) -> None:
        """Hold this run's lock on the server (once), then drop the stores of killed runs. StoreUnavailable when the
        server cannot be reached (``_lock_connection``); StoreError when the lock is another's or the server fails
        meanwhile, and once open, when ``dsn`` is not the one it opened (its stores there would be neither tagged nor
        dropped) or the lock was lost."""
        if self._lock is not None:
            if _place(dsn) != _place(self.dsn):
                raise StoreError(f"fleet store {_where(dsn)}: run {self.run} holds its lock on {_where(self.dsn)}, "
                                 "and makes its stores there only")
            self.held()
            return
        psycopg = _psycopg()
        con = _lock_connection(check_dsn(dsn))
        try:
            con.autocommit = True
            con.execute("SELECT set_config('application_name', %s, false)", (self.tag,))
            if not con.execute("SELECT pg_try_advisory_lock(%s)", (run_key(self.run),)).fetchone()[0]:
                raise StoreError(f"fleet store {_where(dsn)}: the advisory lock of run {self.run} is another's")
            self.sweep(con)
        except BaseException as exc:
            con.close()
            if isinstance(exc, psycopg.Error):
                raise StoreError(f"fleet store {_where(dsn)}: {first_line(exc)}") from None
            raise
        self.dsn, self._lock = dsn, con

    def sweep(self, con) -> list[str]:
        """Drop the tagged stores of every other run whose lock is free (a killed one), holding that lock meanwhile
        so that no other run sweeps them at once; return the names dropped. A lock is per database: one held on
        any database (the run's, or another sweep's on its own) leaves the run's stores alone."""
        runs: dict[str, list[tuple[str, str]]] = {}
        for kind, name, tag in con.execute(_STORES).fetchall():
            if owner(name, tag) not in (None, self.run):
                runs.setdefault(owner(name, tag), []).append((kind, name))
        dropped = []
        for run, stores in runs.items():
            if con.execute("SELECT pg_try_advisory_lock(%s)", (run_key(run),)).fetchone()[0]:
                try:
                    if not con.execute(_HELD_ELSEWHERE, (run_key(run),)).fetchone()[0]:
                        dropped += _drop(con, stores)[0]
                finally:
                    con.execute("SELECT pg_advisory_unlock(%s)", (run_key(run),))
        return dropped

    def _own(self, con) -> list[tuple[str, str, str | None]]:
        return con.execute(_STORES + "WHERE starts_with(name, %s)", (self.run + "_",)).fetchall()

    def held(self):
        """The connection holding this run's lock, checked on the server; StoreError once it is lost (a server
        restart, an idle or an administrator's termination, a dead peer its keepalives found): the lock went with it,
        and the next run to open the server may have dropped this run's stores."""
        psycopg = _psycopg()
        try:
            if not self._lock.broken:
                self._lock.execute("SELECT 1")
        except psycopg.Error as exc:
            self._loss = first_line(exc)
        if self._lock.broken:
            raise StoreError(f"fleet store {_where(self.dsn)}: the lock of run {self.run} was lost "
                             f"({self._loss or 'connection broken'}); the next run to open the server may have "
                             "dropped its stores")
        return self._lock

    def tag_stores(self) -> None:
        """Tag what this run has made so far as its own, so that should it be killed the next run drops it (nothing
        before ``open``). A store dropped meanwhile is passed over; a lost lock is a StoreError (``held``)."""
        if self._lock is None:
            return
        con = self.held()
        psycopg = _psycopg()
        from psycopg import sql

        try:
            for kind, name, tag in self._own(con):
                if tag != self.tag:
                    con.execute(sql.SQL("COMMENT ON {} {} IS {}").format(sql.SQL(kind), sql.Identifier(name),
                                                                         sql.Literal(self.tag)))
        except psycopg.Error as exc:
            if con.broken:
                self._loss = first_line(exc)
                self.held()  # raises: the lock went with the connection
            # else a store dropped meanwhile: a later pass or the run's end sees to it

    def close(self) -> str | None:
        """At the run's end: drop what it made (nothing, and no connection, when it never opened the server), then
        free its lock. Return one warning line naming what was left (a server gone, another suite's ``.ci/fleet.sh
        stop``), which stays tagged for the next run to drop, or None; when the lock was lost meanwhile (``held``),
        a StoreError saying so, and what was left, once all that is done."""
        if self._lock is None:
            return None
        psycopg = _psycopg()
        lost = None
        try:
            self.tag_stores()
        except StoreError as exc:
            lost = exc
        try:
            with psycopg.connect(self.dsn, autocommit=True, connect_timeout=3) as con:
                left = _drop(con, [(kind, name) for kind, name, _ in self._own(con)])[1]
        except psycopg.Error as exc:
            left = [f"{self.run}_* ({first_line(exc)})"]
        finally:
            self._lock.close()
            self._lock = None
        if lost is not None:
            raise StoreError(f"{self.who}: {lost}" + (f"; left on the server: {', '.join(left)}" if left else ""))
        return f"{self.who}: fleet stores left on {_where(self.dsn)} for the next run to drop: {', '.join(left)}" \
            if left else None


def _lock_connection(dsn: str):
    """A connection on which to hold a run's lock: on ``LOCKS_DB``, else, where the server says that database does
    not exist or refuses the DSN's role there (nothing else: a run's lock moved by a passing timeout would be free
    to a sweep that looks on ``LOCKS_DB`` only, an older cellguard's), on the database the DSN itself connects to;
    StoreUnavailable naming each database tried."""
    psycopg = _psycopg()
    from psycopg.conninfo import make_conninfo

    try:
        return psycopg.connect(make_conninfo(dsn, dbname=LOCKS_DB, connect_timeout=3, **_KEEPALIVES))
    except psycopg.OperationalError as exc:
        why = _reason(exc, dsn)
        if not _NO_LOCKS_DB.search(why):
            raise StoreUnavailable(f"fleet store {_where(dsn)} unreachable for the run's lock (database "
                                   f"{LOCKS_DB!r}: {why})") from None
    try:
        return psycopg.connect(make_conninfo(dsn, connect_timeout=3, **_KEEPALIVES))
    except psycopg.OperationalError as exc:
        raise StoreUnavailable(f"fleet store {_where(dsn)} unreachable for the run's lock (database {LOCKS_DB!r}: "
                               f"{why}; the DSN's own: {_reason(exc, dsn)})") from None


def _place(dsn: str) -> tuple:
    """The server a DSN names (host, port, database), however its parameters are ordered or spelt."""
    from psycopg.conninfo import conninfo_to_dict

    given = conninfo_to_dict(dsn)
    return tuple(str(given.get(key, "")) for key in ("host", "hostaddr", "port", "dbname"))
