"""The fleet store on PostgreSQL: every tenant's rows in one database, each tenant fenced off by
row-level security that no SQL it can send removes.

Roles (``D`` is the database name):

- ``D_owner`` (no login) owns the tables, with ``FORCE ROW LEVEL SECURITY``: even it sees no row
  without a policy.
- ``D_t_<tenant>``, one login role per tenant, member of ``D_app``. The tenant is bound at
  connect time by the password it authenticates with: the policies compare rows with
  ``fleet.session_tenant()``, a SECURITY DEFINER lookup of ``session_user``, which only a
  superuser can change (``SET ROLE`` changes ``current_user``, not ``session_user``; there is
  no GUC to forge). Tenants may SELECT and INSERT their own rows; nobody may UPDATE. A tenant
  deletes its own rows only through SECURITY DEFINER functions (``fleet.drop_signature``,
  ``fleet.drop_aggregate``, ``fleet.forget_site``): with no DELETE right it cannot ``LOCK`` a table
  in a mode that would stop every other tenant's push and query. Every tenant connection also
  runs with a ``lock_timeout`` and a ``statement_timeout``, so a wait on another session ends.
- Tenants may not read the server's activity statistics, relation sizes or role list
  (``pg_stat_*``, ``pg_statio_*``, ``pg_*_size``, ``pg_roles``, ``pg_class``): those count every
  customer's rows or name every tenant. The planner's estimates (``EXPLAIN``) still show a
  table's approximate total row count to whoever may read it: PostgreSQL gives no way to hide them.
- ``D_agg`` (no login) reads every row, but only inside the cross-customer functions
  ``fleet.q_<query>(k)``, generated from the named queries (``queries.py``): each refuses when
  fewer than k customers other than the caller have signatures (k = max(the caller's, the store's
  setting, default 5); the refusal does not say how many there are) and drops every group seen at
  fewer than k of them: a tenant's own rows, which it may craft, never make up the k it is shown.

Every SECURITY DEFINER function names its tables with their schema and searches ``pg_temp`` last,
and tenants may not create temporary objects at all: a temporary view called ``signatures`` read
with the definer's rights would hand a tenant every customer's rows.

Uploads are idempotent: a signature's key is (tenant, signature id), an aggregate's (tenant, site,
month, cause, robot model, cell type). A row sent again with other content (fewer fields, once
the policy withholds more; a new count, once a growing folder is pushed again) replaces the one
there: deleted and inserted in one transaction, as tenants update nothing. A batch's aggregates
are the site's counts for the months it covers: the site's other groups of those months (grouped
by a robot model the policy now withholds) are deleted in the same transaction.
"""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import os
import re
import secrets
from collections.abc import Callable, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

from cellguard.errors import CellguardError, ConfigError, OutputError
from cellguard.fleet.export import Batch
from cellguard.fleet.signature import ID_PATTERN
from cellguard.fleet.queries import (MIN_CUSTOMERS, QUERIES, RefusedAggregate, checked, first_line, named, plain,
                                     render)

if TYPE_CHECKING:
    from cellguard.fleet.landing import Landing

SIGNATURE_COLUMNS = ("signature_id", "tenant_id", "site_id", "created_date", "cause", "confidence", "robot_model",
                     "cell_type", "onset_cycle", "detection_delay_cycles", "policy_version", "calibration_version",
                     "cellguard_version", "recovery", "recovery_outcome", "schema_version")
SERVER_DATE = "(now() AT TIME ZONE 'UTC')::date"  # the store's UTC date, as sites count theirs
# a store made for one run and dropped at its end: cg, 8 base-36 characters naming the run, _ and what it is for (a
# benchmark's, a test session's: ``run_stores``); the only name ``FleetStore.drop`` takes
RUN_STORE = re.compile(r"cg[0-9a-z]{8}_[0-9a-z_]{1,9}")
RELATIONS = {"signatures": "fleet.signatures", "effects": "fleet.effects",  # never a name pg_temp could shadow
             "probe": "unnest(%(features)s::text[], %(effects)s::double precision[]) AS probe (feature, effect)"}

# the server's views and functions that count every customer's rows or name every tenant: a tenant reads none
# (revoked from PUBLIC in the store's database only; pg_stats and pg_stats_ext already hide row-secured tables)
_HIDDEN_CATALOG_SQL = r"""
DO $$ DECLARE r record; BEGIN
  FOR r IN SELECT c.oid::regclass AS rel FROM pg_catalog.pg_class c
           WHERE c.relnamespace = 'pg_catalog'::regnamespace AND c.relkind = 'v'
             AND (c.relname LIKE 'pg\_stat\_%' OR c.relname LIKE 'pg\_statio\_%') LOOP
    EXECUTE format('REVOKE ALL ON %s FROM PUBLIC', r.rel);
  END LOOP;
  FOR r IN SELECT p.oid::regprocedure AS fn FROM pg_catalog.pg_proc p
           WHERE p.pronamespace = 'pg_catalog'::regnamespace
             AND (p.proname LIKE 'pg\_stat\_get\_%' OR p.proname LIKE 'pg\_%\_size' OR p.proname = 'pg_lock_status') LOOP
    EXECUTE format('REVOKE ALL ON FUNCTION %s FROM PUBLIC', r.fn);
  END LOOP;
END $$;
REVOKE ALL ON pg_catalog.pg_class, pg_catalog.pg_roles, pg_catalog.pg_user, pg_catalog.pg_group,
  pg_catalog.pg_auth_members, pg_catalog.pg_locks FROM PUBLIC;
"""


# a row dated after the store's tomorrow (a site's record stamped by a clock that ran ahead) would outlive the
# retention counted from its date: refused, whoever sends it (sites hold such rows back; a client may not)
_DATED_AHEAD_SQL = """
CREATE OR REPLACE FUNCTION fleet.not_dated_ahead() RETURNS trigger LANGUAGE plpgsql
  SET search_path = pg_catalog, pg_temp AS $$
DECLARE tomorrow date := (now() AT TIME ZONE 'UTC')::date + 1;
BEGIN
  IF TG_TABLE_NAME = 'signatures' THEN
    IF NEW.created_date > tomorrow THEN
      RAISE EXCEPTION 'created_date % is after the store''s tomorrow (%): a clock that ran ahead dated it',
        NEW.created_date, tomorrow USING ERRCODE = 'check_violation';
    END IF;
  ELSIF NEW.month > to_char(tomorrow, 'YYYY-MM') THEN
    RAISE EXCEPTION 'month % is after the month of the store''s tomorrow (%): a clock that ran ahead dated it',
      NEW.month, tomorrow USING ERRCODE = 'check_violation';
  END IF;
  RETURN NEW;
END $$;
REVOKE ALL ON FUNCTION fleet.not_dated_ahead() FROM PUBLIC;
DROP TRIGGER IF EXISTS not_dated_ahead ON fleet.signatures;
CREATE TRIGGER not_dated_ahead BEFORE INSERT ON fleet.signatures FOR EACH ROW EXECUTE FUNCTION fleet.not_dated_ahead();
DROP TRIGGER IF EXISTS not_dated_ahead ON fleet.aggregates;
CREATE TRIGGER not_dated_ahead BEFORE INSERT ON fleet.aggregates FOR EACH ROW EXECUTE FUNCTION fleet.not_dated_ahead();
"""


class StoreError(CellguardError):
    """The fleet store refused or failed an operation (not a connection problem)."""


class StoreUnavailable(StoreError):
    """The fleet store cannot be reached; what was to be sent stays in the outbox."""


def ci_admin_dsn() -> str | None:
    """The admin DSN of the server ``.ci/fleet.sh`` started: ``CELLGUARD_FLEET_ADMIN_DSN``, else the file
    ``CELLGUARD_FLEET_DSN_FILE`` (default /tmp/cellguard-fleet-dsn) writes; None when neither is there."""
    dsn = os.environ.get("CELLGUARD_FLEET_ADMIN_DSN")
    if dsn:
        return dsn
    path = Path(os.environ.get("CELLGUARD_FLEET_DSN_FILE", "/tmp/cellguard-fleet-dsn"))
    return path.read_text().strip() if path.is_file() else None


def _psycopg():
    try:
        import psycopg
    except ImportError:
        raise ConfigError("the fleet store needs psycopg; pip install 'cellguard[fleet]'") from None
    return psycopg


MALFORMED_DSN = ("fleet store DSN (--store or CELLGUARD_FLEET_DSN): malformed; expected key=value pairs "
                 "(host=... dbname=... user=...) or a postgresql:// URI")


def connect(dsn: str, timeout_s: float = 3.0):
    """A connection, or StoreUnavailable naming the server (never the password); a malformed DSN is
    a ConfigError that does not echo it."""
    psycopg = _psycopg()
    where = _where(dsn)
    try:
        return psycopg.connect(dsn, connect_timeout=max(1, round(timeout_s)))
    except psycopg.OperationalError as exc:
        raise StoreUnavailable(f"fleet store {where} unreachable ({_reason(exc, dsn)})") from None
    except psycopg.ProgrammingError:  # libpq could not parse it: its message may quote the DSN, password included
        raise ConfigError(MALFORMED_DSN) from None


def check_dsn(dsn: str) -> str:
    """``dsn`` if libpq can parse it, else ConfigError (the DSN is not echoed: it may hold a password)."""
    psycopg = _psycopg()
    from psycopg.conninfo import conninfo_to_dict
    try:
        conninfo_to_dict(dsn)
    except psycopg.Error:
        raise ConfigError(MALFORMED_DSN) from None
    return dsn


def _reason(exc: Exception, dsn: str) -> str:
    """The first meaningful line of a driver error, stripped, with the DSN's password blanked out."""
    line = first_line(exc)
    from psycopg.conninfo import conninfo_to_dict
    try:
        password = conninfo_to_dict(dsn).get("password")
    except Exception:  # noqa: BLE001 - nothing to blank out in a DSN libpq cannot parse
        password = None
    return line.replace(password, "***") if password and len(password) >= 4 else line


def _where(dsn: str) -> str:
    from psycopg.conninfo import conninfo_to_dict
    try:
        d = conninfo_to_dict(dsn)
    except Exception:  # noqa: BLE001 - a malformed DSN is named as such, never echoed (it may hold a password)
        return "(malformed DSN)"
    return f"{d.get('host', 'localhost')}:{d.get('port', 5432)}/{d.get('dbname', '?')}"


class FleetStore:
    """The operator's side: install the schema, add tenants, set k. Runs as a superuser."""

    def __init__(self, admin_dsn: str, database: str = "cellguard_fleet"):
        if not database.replace("_", "").isalnum() or not database.islower() or len(database) > 20:
            raise ConfigError(f"database: {database!r}; expected lower-case letters, digits and _ (at most 20)")
        self.admin_dsn, self.database = check_dsn(admin_dsn), database
        self.owner, self.agg, self.app = f"{database}_owner", f"{database}_agg", f"{database}_app"

    def tenant_role(self, tenant_id: str) -> str:
        """The tenant's login role. Its id is checked as every other reader of a tenant id checks it (``ID_PATTERN``,
        at most 40): a longer one made a role name past PostgreSQL's 63 bytes, which it cut short, so a tenant was
        added that could never push (a signature refuses its id), and a second sharing its first 40 characters failed
        with the driver's raw "role ... already exists"."""
        if not isinstance(tenant_id, str) or not re.fullmatch(ID_PATTERN, tenant_id):
            raise ConfigError(f"tenant: expected an opaque id matching {ID_PATTERN}, got {tenant_id!r}")
        return f"{self.database}_t_{tenant_id}"

    def install(self, reset: bool = False) -> None:
        """Create the database, roles, tables, policies and functions (``reset``: drop them first). On a
        database already there, bring its functions and grants up to date (an older store gets today's)."""
        _psycopg()
        from psycopg import sql
        db = sql.Identifier(self.database)
        with connect(self.admin_dsn) as con:
            con.autocommit = True
            exists = con.execute("SELECT 1 FROM pg_database WHERE datname = %s", (self.database,)).fetchone()
            if reset or not exists:
                self._drop(con)
                for role in (self.owner, self.agg, self.app):
                    con.execute(sql.SQL("CREATE ROLE {} NOLOGIN NOINHERIT").format(sql.Identifier(role)))
                con.execute(sql.SQL("CREATE DATABASE {}").format(db))
            con.execute(sql.SQL("REVOKE ALL ON DATABASE {} FROM PUBLIC").format(db))
            con.execute(sql.SQL("REVOKE TEMPORARY ON DATABASE {} FROM {}").format(db, sql.Identifier(self.app)))
            con.execute(sql.SQL("GRANT CONNECT ON DATABASE {} TO {}").format(db, sql.Identifier(self.app)))
        with connect(self._admin_db()) as con:
            with con.transaction():
                con.execute(self._schema_sql() if reset or not exists else self._session_tenant_sql())
                con.execute(self._tenant_rights_sql())
                con.execute(_DATED_AHEAD_SQL)
                for q in QUERIES.values():
                    if q.cross_customer:
                        con.execute(self._function_sql(q))

    def drop(self) -> list[str]:
        """Drop this store's database and roles (its own three and its tenants'), as a store made for one run (a
        benchmark's, a test session's: ``RUN_STORE``) ends; any other name is refused, a fleet's store is dropped by
        hand. What is not there is passed over: a second drop drops nothing. Returns the names dropped."""
        if not RUN_STORE.fullmatch(self.database):
            raise ConfigError(f"database: {self.database!r} is not a store made for one run (expected "
                              f"{RUN_STORE.pattern}); drop refuses it")
        with connect(self.admin_dsn) as con:
            con.autocommit = True
            return self._drop(con)

    def _drop(self, con) -> list[str]:
        """Drop the database (its sessions ended) and then this store's roles on ``con``; the names dropped."""
        from psycopg import sql
        there = con.execute("SELECT datname FROM pg_database WHERE datname = %s", (self.database,)).fetchall()
        con.execute(sql.SQL("DROP DATABASE IF EXISTS {} WITH (FORCE)").format(sql.Identifier(self.database)))
        roles = self._roles(con)
        for role in roles:
            con.execute(sql.SQL("DROP ROLE {}").format(sql.Identifier(role)))
        return [d for (d,) in there] + roles

    def _roles(self, con) -> list[str]:
        """This store's roles, by exact name: its own three and its tenants' (members of its app role);
        never another store's whose name merely starts the same (``cgz`` and ``cgz_fleet``)."""
        own = (self.owner, self.agg, self.app)
        tenants = con.execute("SELECT m.rolname FROM pg_auth_members a JOIN pg_roles m ON m.oid = a.member "
                              "JOIN pg_roles g ON g.oid = a.roleid WHERE g.rolname = %s", (self.app,)).fetchall()
        there = con.execute("SELECT rolname FROM pg_roles WHERE rolname = ANY(%s)", (list(own),)).fetchall()
        return [r for (r,) in tenants + there]

    def add_tenant(self, tenant_id: str, host: str = "127.0.0.1") -> str:
        """Create the tenant's login role with a fresh password; return the tenant's DSN."""
        from psycopg import sql
        from psycopg.conninfo import conninfo_to_dict, make_conninfo
        role, password = self.tenant_role(tenant_id), secrets.token_urlsafe(24)
        with connect(self._admin_db()) as con, con.transaction():
            con.execute(sql.SQL("CREATE ROLE {} LOGIN INHERIT NOSUPERUSER NOCREATEDB NOCREATEROLE NOBYPASSRLS "
                                "PASSWORD {} IN ROLE {}").format(sql.Identifier(role), sql.Literal(password),
                                                                 sql.Identifier(self.app)))
            con.execute("INSERT INTO fleet.tenants (tenant_id, role_name) VALUES (%s, %s)", (tenant_id, role))
        port = conninfo_to_dict(self.admin_dsn).get("port", "5432")
        return make_conninfo(host=host, port=port, dbname=self.database, user=role, password=password)

    def set_min_customers(self, k: int) -> None:
        if isinstance(k, bool) or not isinstance(k, int) or not 2 <= k <= 1000:
            raise ConfigError(f"min_customers: expected an integer 2..1000, got {k!r}")
        with connect(self._admin_db()) as con, con.transaction():
            con.execute("UPDATE fleet.settings SET min_customers = %s", (k,))

    def admin(self):
        """A superuser connection to the fleet database (tests, retention jobs)."""
        return connect(self._admin_db())

    def _admin_db(self) -> str:
        from psycopg.conninfo import make_conninfo
        return make_conninfo(self.admin_dsn, dbname=self.database)

    def _schema_sql(self) -> str:
        o, a, g = f'"{self.owner}"', f'"{self.app}"', f'"{self.agg}"'
        return f"""
REVOKE ALL ON SCHEMA public FROM PUBLIC;
CREATE SCHEMA fleet AUTHORIZATION {o};
GRANT USAGE ON SCHEMA fleet TO {a}, {g};
CREATE TABLE fleet.tenants (tenant_id text PRIMARY KEY, role_name name UNIQUE NOT NULL);
CREATE TABLE fleet.settings (one boolean PRIMARY KEY DEFAULT true CHECK (one),
                             min_customers int NOT NULL CHECK (min_customers >= 2));
INSERT INTO fleet.settings (min_customers) VALUES ({MIN_CUSTOMERS});
{self._session_tenant_sql()}
CREATE TABLE fleet.signatures (
  signature_id text NOT NULL, tenant_id text NOT NULL REFERENCES fleet.tenants, site_id text NOT NULL,
  created_date date NOT NULL, cause text NOT NULL, confidence double precision, robot_model text, cell_type text,
  onset_cycle bigint, detection_delay_cycles bigint, policy_version text, calibration_version text,
  cellguard_version text, recovery text, recovery_outcome text, schema_version int NOT NULL,
  PRIMARY KEY (tenant_id, signature_id));
CREATE TABLE fleet.effects (
  tenant_id text NOT NULL, signature_id text NOT NULL, feature text NOT NULL, effect double precision NOT NULL,
  PRIMARY KEY (tenant_id, signature_id, feature),
  FOREIGN KEY (tenant_id, signature_id) REFERENCES fleet.signatures ON DELETE CASCADE);
CREATE TABLE fleet.aggregates (
  row_id text NOT NULL, tenant_id text NOT NULL REFERENCES fleet.tenants, site_id text NOT NULL, month text NOT NULL,
  cause text NOT NULL, robot_model text, cell_type text, signatures bigint NOT NULL, policy_version text NOT NULL,
  PRIMARY KEY (tenant_id, row_id));
ALTER TABLE fleet.tenants OWNER TO {o};
ALTER TABLE fleet.settings OWNER TO {o};
ALTER TABLE fleet.signatures OWNER TO {o};
ALTER TABLE fleet.effects OWNER TO {o};
ALTER TABLE fleet.aggregates OWNER TO {o};
GRANT SELECT ON fleet.settings TO {g};
""" + "".join(f"""
ALTER TABLE fleet.{t} ENABLE ROW LEVEL SECURITY;
ALTER TABLE fleet.{t} FORCE ROW LEVEL SECURITY;
CREATE POLICY own_rows ON fleet.{t} FOR ALL TO {a}
  USING (tenant_id = fleet.session_tenant()) WITH CHECK (tenant_id = fleet.session_tenant());
CREATE POLICY cross_customer ON fleet.{t} FOR SELECT TO {g} USING (true);
GRANT SELECT, INSERT ON fleet.{t} TO {a};
GRANT SELECT ON fleet.{t} TO {g};
""" for t in ("signatures", "effects", "aggregates"))

    def _tenant_rights_sql(self) -> str:
        """What a tenant may do beyond its own rows' SELECT and INSERT, on a new store and an older one:
        delete them only through the owner's functions (no DELETE right, so no table lock that stops the
        others), and read no statistics, size or role list of the server's (they count every customer)."""
        o, a = f'"{self.owner}"', f'"{self.app}"'
        mine = "tenant_id = fleet.session_tenant()"
        out = "".join(f"""
REVOKE DELETE ON fleet.{t} FROM {a};
DROP POLICY IF EXISTS owner_deletes ON fleet.{t};
CREATE POLICY owner_deletes ON fleet.{t} FOR ALL TO {o} USING ({mine});
""" for t in ("signatures", "effects", "aggregates")) + f"""
CREATE OR REPLACE FUNCTION fleet.drop_signature(sid text) RETURNS bigint LANGUAGE sql SECURITY DEFINER
  SET search_path = pg_catalog, pg_temp AS $$
  WITH d AS (DELETE FROM fleet.signatures WHERE {mine} AND signature_id = sid RETURNING 1) SELECT count(*) FROM d $$;
CREATE OR REPLACE FUNCTION fleet.drop_aggregate(rid text) RETURNS bigint LANGUAGE sql SECURITY DEFINER
  SET search_path = pg_catalog, pg_temp AS $$
  WITH d AS (DELETE FROM fleet.aggregates WHERE {mine} AND row_id = rid RETURNING 1) SELECT count(*) FROM d $$;
CREATE OR REPLACE FUNCTION fleet.forget_site(site text, before date, before_month text) RETURNS bigint
  LANGUAGE sql SECURITY DEFINER SET search_path = pg_catalog, pg_temp AS $$
  WITH s AS (DELETE FROM fleet.signatures WHERE {mine} AND site_id = site AND created_date < before RETURNING 1),
       g AS (DELETE FROM fleet.aggregates WHERE {mine} AND site_id = site AND month < before_month RETURNING 1)
  SELECT (SELECT count(*) FROM s) + (SELECT count(*) FROM g) $$;
""" + "".join(f"""
ALTER FUNCTION fleet.{f} OWNER TO {o};
REVOKE ALL ON FUNCTION fleet.{f} FROM PUBLIC;
GRANT EXECUTE ON FUNCTION fleet.{f} TO {a};
""" for f in ("drop_signature(text)", "drop_aggregate(text)", "forget_site(text, date, text)"))
        return out + _HIDDEN_CATALOG_SQL

    def _session_tenant_sql(self) -> str:
        return f"""
CREATE OR REPLACE FUNCTION fleet.session_tenant() RETURNS text LANGUAGE sql STABLE SECURITY DEFINER
  SET search_path = pg_catalog, pg_temp AS $$ SELECT tenant_id FROM fleet.tenants WHERE role_name = session_user $$;
ALTER FUNCTION fleet.session_tenant() OWNER TO "{self.owner}";
REVOKE ALL ON FUNCTION fleet.session_tenant() FROM PUBLIC;
GRANT EXECUTE ON FUNCTION fleet.session_tenant() TO "{self.app}", "{self.agg}";
"""

    def _function_sql(self, q) -> str:
        cols = ", ".join(f"{c} {t}" for c, t in q.columns)
        body = render(q, exprs={"k": "k_eff", "caller": "caller"}, relations=RELATIONS)
        return f"""
CREATE OR REPLACE FUNCTION fleet.q_{q.name}(min_customers int DEFAULT {MIN_CUSTOMERS}) RETURNS TABLE ({cols})
LANGUAGE plpgsql STABLE SECURITY DEFINER SET search_path = fleet, pg_catalog, pg_temp AS $fn$
#variable_conflict use_column
DECLARE
  k_eff int := greatest(min_customers, (SELECT s.min_customers FROM fleet.settings s));
  caller text := coalesce(fleet.session_tenant(), '');  -- its own rows count toward no k
  n int := (SELECT count(DISTINCT t.tenant_id) FROM fleet.signatures t WHERE t.tenant_id <> caller);
BEGIN
  IF n < k_eff THEN
    RAISE EXCEPTION 'cross-customer query {q.name} refused: signatures from fewer than % customers', k_eff
      USING ERRCODE = 'insufficient_privilege';
  END IF;
  RETURN QUERY {body};
END $fn$;
ALTER FUNCTION fleet.q_{q.name}(int) OWNER TO "{self.agg}";
REVOKE ALL ON FUNCTION fleet.q_{q.name}(int) FROM PUBLIC;
GRANT EXECUTE ON FUNCTION fleet.q_{q.name}(int) TO "{self.app}";
"""


class TenantStore:
    """A tenant's side: push batches and query, every statement as the tenant's own role.

    ``timeout_s`` bounds the connect, ``lock_timeout_s`` any wait on a lock another session holds and
    ``statement_timeout_s`` any one statement: no other session can keep a push or a query waiting."""

    def __init__(self, dsn: str, timeout_s: float = 3.0, lock_timeout_s: float = 10.0,
                 statement_timeout_s: float = 300.0):
        self.dsn, self.timeout_s = check_dsn(dsn), timeout_s
        self.lock_timeout_s, self.statement_timeout_s = lock_timeout_s, statement_timeout_s
        self.where = _where(dsn)

    def connection(self):
        con = connect(self.dsn, self.timeout_s)
        con.execute("SELECT set_config('search_path', 'fleet, pg_catalog', false), "
                    "set_config('lock_timeout', %s, false), set_config('statement_timeout', %s, false)",
                    (f"{round(self.lock_timeout_s * 1000)}ms", f"{round(self.statement_timeout_s * 1000)}ms"))
        con.commit()
        return con

    def push(self, batch: Batch, stage: Callable[[], Landing] | None = None) -> tuple[int, int]:
        """Insert the batch's rows in one transaction, each replacing its earlier copy: (rows new or
        changed, rows already there as they are). ``stage`` (the lake's write) runs before the commit: if
        it fails, nothing is committed. What it staged is published only once the commit succeeded and
        discarded when the store refused the batch (at the commit too: a deferred constraint); where the
        commit's outcome is not known (the server lost, the push stopped) it is left for the next push to
        bring to what the store holds (``landing.reconcile``)."""
        landing = None
        try:
            with self._writing(f"refused the batch of tenant {batch.tenant_id}") as cur:
                new = _insert(cur, batch)
                landing = stage() if stage is not None else None
        except BaseException as exc:
            if landing is not None:
                refused = isinstance(exc, StoreError) and not isinstance(exc, StoreUnavailable)
                landing.discard() if refused else landing.release()
            raise
        if landing is not None:
            try:
                landing.publish()
            except OutputError as exc:  # ``landing.Unpublished``: committed, so the caller counts it as taken
                exc.taken = (new, batch.rows - new)
                raise
        return new, batch.rows - new

    def tenant(self) -> str | None:
        """The tenant these credentials log in as (``fleet.session_tenant()``; None: a role that is no tenant's):
        what a withdrawal checks the policy's tenant against, as it can delete no other tenant's rows."""
        with self.connection() as con, self._mapped("could not read its tenant"):
            return con.execute("SELECT fleet.session_tenant()").fetchone()[0]

    def held(self, signature_ids: Sequence[str]) -> dict[str, dict]:
        """This tenant's stored signatures among ``signature_ids``, each with its ``effects``: what a lake's staged
        rows are reconciled with (``landing.reconcile``)."""
        with self.connection() as con, self._mapped("could not read its signatures"):
            ids = list(signature_ids)
            rows = con.execute(f"SELECT {', '.join(SIGNATURE_COLUMNS)} FROM fleet.signatures "
                               "WHERE signature_id = ANY(%s)", (ids,)).fetchall()
            effects = con.execute("SELECT signature_id, feature, effect FROM fleet.effects "
                                  "WHERE signature_id = ANY(%s)", (ids,)).fetchall()
        out = {r[0]: {**dict(zip(SIGNATURE_COLUMNS, r)), "effects": {}} for r in rows}
        for sid, feature, effect in effects:
            out[sid]["effects"][feature] = effect
        return out

    def forget(self, site_id: str, keep_days: int | None = None) -> int:
        """Delete this tenant's signatures of ``site_id`` more than ``keep_days`` old (its retention) and its
        aggregates of the months wholly before; every row of the site when ``keep_days`` is None (consent
        withdrawn). The days are counted on the server's clock, in the statement: a site's clock set wrong
        does not choose what is deleted. Returns the rows deleted."""
        with self._writing(f"refused to delete the rows of site {site_id}") as cur:
            cur.execute("SELECT fleet.forget_site(%(site)s, before, to_char(before, 'YYYY-MM')) FROM "
                        f"(SELECT coalesce({SERVER_DATE} - %(days)s::int, DATE '9999-12-31') AS before) cutoff",
                        {"site": site_id, "days": keep_days})
            return cur.fetchone()[0]

    def today(self) -> dt.date:
        """The server's UTC date: the one clock every site's retention is counted on."""
        with self.connection() as con, self._mapped("could not read its date"):
            return con.execute(f"SELECT {SERVER_DATE}").fetchone()[0]

    @contextmanager
    def _writing(self, refused: str):
        """A cursor in one transaction as this tenant; a refusal is a StoreError saying ``refused`` and why,
        a lost server StoreUnavailable (rolled back: what was to be sent stays queued)."""
        psycopg = _psycopg()
        with self.connection() as con, self._mapped(refused):
            try:
                with con.transaction(), con.cursor() as cur:
                    yield cur
            except psycopg.errors.InsufficientPrivilege as exc:
                raise StoreError(f"fleet store {self.where}: {refused} ({exc.diag.message_primary})") from None

    def run(self, query: str, params: Mapping | None = None, probe: Sequence[tuple[str, float]] = (),
            scope: str = "fleet") -> list[dict]:
        """A named query: ``scope`` "fleet" (cross-customer, k applies) or "own" (this tenant's rows)."""
        psycopg = _psycopg()
        q = named(query)
        if scope not in ("fleet", "own"):
            raise ConfigError(f"--scope: {scope!r}; allowed: fleet, own")
        fleet_wide = scope == "fleet" and q.cross_customer
        if fleet_wide:  # checked here as the lake checks it: the function's argument is an int
            k = checked(q, "k", (params or {}).get("k", MIN_CUSTOMERS))
        with self.connection() as con, self._mapped(f"query {q.name} failed"), con.transaction(), \
                con.cursor() as cur:
            try:
                if fleet_wide:
                    cur.execute(f"SELECT * FROM fleet.q_{q.name}(%s)", (k,))
                else:  # the probe is bound as arrays: tenants may create no temporary table
                    cur.execute(render(q, params, {"k": "1"}, relations=RELATIONS),
                                {"features": [f for f, _ in probe], "effects": [float(e) for _, e in probe]})
            except psycopg.errors.InsufficientPrivilege as exc:
                raise RefusedAggregate(exc.diag.message_primary) from None
            cols = [d.name for d in cur.description]
            return [plain(dict(zip(cols, r))) for r in cur.fetchall()]

    @contextmanager
    def _mapped(self, refused: str):
        """A driver error inside as one line: a wait cut short or a lost server StoreUnavailable, any other
        refusal (a constraint, a type) a StoreError saying ``refused`` and why."""
        psycopg = _psycopg()
        try:
            yield
        except (psycopg.errors.LockNotAvailable, psycopg.errors.QueryCanceled) as exc:
            raise StoreUnavailable(self._busy(exc)) from None
        except psycopg.OperationalError as exc:
            raise StoreUnavailable(f"fleet store {self.where} lost mid-transaction ({exc.__class__.__name__})") \
                from None
        except psycopg.Error as exc:
            raise StoreError(f"fleet store {self.where}: {refused} ({_reason(exc, self.dsn)})") from None

    def _busy(self, exc: Exception) -> str:
        """A wait cut short by ``lock_timeout`` or ``statement_timeout``, in one line."""
        limit = (f"lock_timeout {self.lock_timeout_s:g} s" if isinstance(exc, _psycopg().errors.LockNotAvailable)
                 else f"statement_timeout {self.statement_timeout_s:g} s")
        return f"fleet store {self.where} busy: gave up after its {limit} ({_reason(exc, self.dsn)})"


def _insert(cur, batch: Batch) -> int:
    """Insert ``batch``'s rows, each replacing its earlier copy; the rows new or changed."""
    new = 0
    for s in batch.signatures:
        effects = sorted((s.get("effects") or {}).items())
        inserted = _replace(cur, "signatures", {c: s.get(c) for c in SIGNATURE_COLUMNS},
                            ("tenant_id", "signature_id"), same=_SAME_EFFECTS, has_effects=bool(effects))
        if inserted:
            cur.executemany("INSERT INTO fleet.effects (tenant_id, signature_id, feature, effect) "
                            "VALUES (%s, %s, %s, %s)",
                            [(s["tenant_id"], s["signature_id"], f, e) for f, e in effects])
        new += inserted
    groups = [{"tenant_id": batch.tenant_id, "site_id": batch.site_id, "month": r["month"], "cause": r["cause"],
               "robot_model": r["robot_model"], "cell_type": r["cell_type"]} for r in batch.aggregates]
    _drop_other_groups(cur, batch.site_id, groups)
    for r, row in zip(batch.aggregates, groups):
        new += _replace(cur, "aggregates", {"row_id": _group_key(row), **row, "signatures": r["signatures"],
                                            "policy_version": batch.policy_version}, tuple(row))
    return new


_DROP = {"signatures": ("drop_signature", "signature_id"), "aggregates": ("drop_aggregate", "row_id")}
# a signature's effects are all there or none (withheld): its id is the hash of them all
_SAME_EFFECTS = ("EXISTS (SELECT 1 FROM fleet.effects e WHERE e.tenant_id = %(tenant_id)s "
                 "AND e.signature_id = %(signature_id)s) = %(has_effects)s")


def _replace(cur, table: str, row: Mapping, key: Sequence[str], same: str = "true", **params) -> int:
    """Insert ``row`` into ``fleet.<table>``, first deleting (through ``fleet.<drop>``, as tenants hold no
    DELETE right) a row with the same ``key`` whose values differ (or for which the SQL condition ``same``
    fails). 1 if it was inserted, 0 if it was there as it is."""
    cols, values = ", ".join(row), ", ".join(f"%({c})s" for c in row)
    match = " AND ".join(f"{k} IS NOT DISTINCT FROM %({k})s" for k in key)
    drop, by = _DROP[table]
    cur.execute(f"SELECT fleet.{drop}({by}) FROM fleet.{table} WHERE {match} "
                f"AND NOT (({cols}) IS NOT DISTINCT FROM ({values}) AND {same})", {**row, **params})
    cur.execute(f"INSERT INTO fleet.{table} ({cols}) VALUES ({values}) ON CONFLICT DO NOTHING", row)
    return cur.rowcount


def _drop_other_groups(cur, site_id: str, groups: Sequence[Mapping]) -> None:
    """Delete the site's aggregates of the months ``groups`` cover that are none of them: a batch's counts are
    the site's for those months (a group the policy now merges, withholding its robot model, is not left beside
    the merged one to be counted twice)."""
    if groups:
        cur.execute("SELECT fleet.drop_aggregate(row_id) FROM fleet.aggregates WHERE site_id = %s "
                    "AND month = ANY(%s) AND row_id <> ALL(%s)",
                    (site_id, sorted({g["month"] for g in groups}), [_group_key(g) for g in groups]))


def _group_key(group: Mapping) -> str:
    """An aggregate's key: its tenant, site, month, cause, robot model and cell type, hashed."""
    return hashlib.sha256(json.dumps(list(group.values())).encode()).hexdigest()[:32]
