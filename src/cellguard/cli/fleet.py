"""`cellguard fleet push/query/similar/audit/withdraw`: fault signatures pooled across sites under each
customer's data policy. The store's DSN (the tenant's own credentials) comes from ``--store`` or
``CELLGUARD_FLEET_DSN``; the site's audit log, outbox and key live in ``--site-dir``. Every line is
printed through ``say``: as written, never wrapped (scripts read them), control characters escaped
(a store, a lake or another tenant wrote the values)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import typer

from cellguard.cli import stdout
from cellguard.cli.app import app
from cellguard.cli.errors import fail
from cellguard.cli.text import printable, say
from cellguard.errors import CellguardError

fleet_app = typer.Typer(no_args_is_help=True, help="Fault signatures pooled across sites under each customer's data policy.")
app.add_typer(fleet_app, name="fleet")

STORE = typer.Option(None, "--store", envvar="CELLGUARD_FLEET_DSN", show_envvar=True,
                     help="The fleet store's DSN with this tenant's credentials.")
SITE_DIR = typer.Option(Path("cellguard-fleet"), "--site-dir", help="This site's audit log and outbox.")
JSON = typer.Option(False, "--json", help="Print one JSON document on stdout.")
ACCEPTANCE = typer.Option(None, "--acceptance", help="A record folder whose acceptance cycles are the baseline of "
                          "every run (a cell commissioned once); default: each run's own acceptance cycles.")


def _store(dsn: str | None):
    from cellguard.fleet.store import TenantStore
    return TenantStore(dsn) if dsn else None


@fleet_app.command()
def push(
    folder: Path = typer.Argument(..., help="A run folder (record.mcap) or a folder of run folders."),
    policy: Path = typer.Option(..., "--policy", help="The customer's data policy (YAML)."),
    store: str | None = STORE,
    site_dir: Path = SITE_DIR,
    lake: Path | None = typer.Option(None, "--lake", help="Also land the sent signatures as Parquet here."),
    acceptance: Path | None = ACCEPTANCE,
    as_json: bool = JSON,
) -> None:
    """Diagnose the runs in FOLDER and send their fault signatures as the policy allows; queue if the store is down.
    Queued batches go only as the policy in force allows; one it does not, or one that cannot be read or
    that the store refuses, stays queued and is named on stderr (exit 1 for the last two); a run whose diagnosis
    files cannot be kept beside it (read-only storage) is pushed, with one warning line each (exit 1); a run whose
    record is not whole (truncated, damaged, still being written) or has too few cycles to diagnose is not: one
    warning line each (exit 1). A record met twice (a link, a copy) is read once."""
    from cellguard.cli.diagnose import warn_if_unkept
    from cellguard.fleet.from_record import site_signatures
    from cellguard.fleet.lake import check_lake
    from cellguard.fleet.policy import load_policy
    from cellguard.fleet.push import check_history, check_site
    from cellguard.fleet.push import push as do_push

    try:
        pol = load_policy(policy)
        tenant_store = _store(store)  # a malformed DSN, a --lake that is a file, a --site-dir that is a file or
        if lake is not None:  # holds a link, a site that must withdraw first: refused before the diagnosis
            check_lake(lake)
        check_site(site_dir)
        check_history(site_dir, pol)
        unkept: list[str] = []
        skipped: list[str] = []
        copies: list[str] = []  # folders holding a record already read (a link, a backup copy): diagnosed once
        sigs = (site_signatures(folder, pol, acceptance, unkept, skipped, copies=copies)
                if pol.export != "nothing" else [])
        result = do_push(sigs, pol, site_dir, tenant_store, lake)
        stdout.written(f"batch {result.batch.batch_id} in the audit log of {site_dir}")
    except CellguardError as exc:
        fail(exc)
    if as_json:
        sys.stdout.write(json.dumps({**result.to_dict(), "copies_skipped": len(copies)}) + "\n")
    else:
        b = result.batch
        say(f"fleet push: {b.export}, {b.rows} row(s) exported, {b.withheld_rows} kept at the site "
            f"(policy {b.policy_version}); {result.new_rows} new, {result.duplicate_rows} already in the store; "
            f"{len(copies)} copies of records already read skipped; "
            f"{result.retention_removed} row(s) deleted by retention; {result.queued} batch(es) queued", err=False)
    # the lake takes what the store took: a user with a lake and no store read the README's line as "the lake gets them"
    landed = f"; nothing landed in {lake}: it takes what the store took" if lake is not None else ""
    if result.unavailable:
        sys.stderr.write(f"{result.unavailable}; {result.queued} batch(es) kept in {Path(site_dir) / 'outbox'}, "
                         f"sent on the next push{landed}\n")
    elif store is None and result.queued:
        sys.stderr.write(f"no --store given: {result.queued} batch(es) kept in {Path(site_dir) / 'outbox'}{landed}\n")
    if result.new_key:
        _new_key_note(result.new_key)
    for line in (*result.held, *result.trimmed):
        sys.stderr.write(f"note: {printable(line)}\n")
    for line in filter(None, (*result.failed, result.dated_ahead)):
        sys.stderr.write(f"warning: {printable(line)}\n")
    if max(warn_if_unkept(unkept), _warn_if_skipped(skipped)) or result.failed or result.dated_ahead:
        raise typer.Exit(1)


def _warn_if_skipped(skipped: list[str]) -> int:
    """One warning line per run left out (its record not whole, or too short to diagnose); the exit code: 1 then,
    else 0."""
    for line in skipped:
        say(f"warning: {line}")
    return 1 if skipped else 0


def _new_key_note(path: str) -> None:
    sys.stderr.write(f"note: {printable(path)}: a new site key; signature ids are keyed with it, so keep it with the "
                     f"site (a push from another --site-dir makes another key and stores every signature again)\n")


@fleet_app.command()
def query(
    name: str = typer.Argument(..., help="frequency, introduced, fixes or similar."),
    lake: Path | None = typer.Option(None, "--lake", help="Run on this Parquet lake instead of the store."),
    engine: str = typer.Option("duckdb", "--engine", help="On a lake: duckdb or spark."),
    spark_master: str = typer.Option("local[2]", "--spark-master", help="Spark master URL (spark://HOST:7077)."),
    k: int = typer.Option(5, "--k", help="Least number of distinct customers besides yours behind a "
                          "cross-customer row (1..1000000; never under the store's or lake's least)."),
    scope: str = typer.Option("fleet", "--scope", help="fleet (cross-customer, k applies) or own (your rows)."),
    tenant: str | None = typer.Option(None, "--tenant", help="On a lake: query with this tenant's rights (its own "
                                      "folder; cross-customer only over k customers). Without it: the operator."),
    store: str | None = STORE,
    as_json: bool = JSON,
) -> None:
    """Run a named fleet query on the store (as this tenant) or on a Parquet lake (DuckDB or Spark)."""
    from cellguard.errors import ConfigError
    from cellguard.fleet.queries import named

    try:
        q = named(name)
        params = {"k": k} if "k" in q.defaults else {}
        if lake is not None:
            if engine == "duckdb":
                from cellguard.fleet.duckdb_engine import DuckDBEngine
                eng = DuckDBEngine(lake, tenant)
            elif engine == "spark":
                from cellguard.fleet.spark_engine import SparkEngine
                eng = SparkEngine(lake, spark_master, tenant)
            else:
                raise ConfigError(f"--engine: {engine!r}; allowed: duckdb, spark")
            try:
                rows = eng.run(name, params, scope=scope)
            finally:
                eng.close()
        else:
            if not store:
                raise ConfigError("--store: no fleet store DSN (or CELLGUARD_FLEET_DSN); or give --lake")
            rows = _store(store).run(name, params, scope=scope)
    except CellguardError as exc:
        fail(exc)
    if as_json:
        sys.stdout.write(json.dumps({"query": name, "rows": rows}) + "\n")
        return
    say(f"{name}: {q.doc} ({len(rows)} row(s))", err=False)
    for r in rows:
        say("  " + ", ".join(f"{c}={v}" for c, v in r.items()), err=False)


@fleet_app.command()
def similar(
    target: str = typer.Argument(..., help="A run folder (its findings) or one of your signature ids."),
    policy: Path | None = typer.Option(None, "--policy", help="For a run folder: this site's data policy."),
    limit: int = typer.Option(5, "--limit", help="Neighbours per finding (1..1000000)."),
    acceptance: Path | None = ACCEPTANCE,
    store: str | None = STORE,
    site_dir: Path = SITE_DIR,
    as_json: bool = JSON,
) -> None:
    """The nearest signatures from other sites (same robot model first), with what fixed them and how often.
    A run folder's findings are sent to the store as probes: only under a policy that exports signatures, and
    logged in the audit log of --site-dir first; a run whose record is not whole is left out (one warning line
    each, exit 1)."""
    from cellguard.cli.diagnose import warn_if_unkept
    from cellguard.errors import ConfigError
    from cellguard.fleet import similar as sim
    from cellguard.fleet.audit import check_log, check_site_dir
    from cellguard.fleet.queries import checked, named

    unkept: list[str] = []  # a run folder on read-only storage: its diagnosis's files not kept beside it
    skipped: list[str] = []  # a run whose record is not whole
    try:
        checked(named("similar"), "limit", limit)  # every option before anything is diagnosed, logged or sent
        if not store:
            raise ConfigError("--store: no fleet store DSN (or CELLGUARD_FLEET_DSN)")
        st = _store(store)
        if Path(target).is_dir():
            from cellguard.fleet.from_record import site_signatures
            from cellguard.fleet.policy import load_policy
            if policy is None:
                raise ConfigError("--policy: needed with a run folder (it names this site)")
            site_policy = load_policy(policy)
            sim.check_policy(site_policy)
            check_site_dir(site_dir, missing_ok=True)  # the probes are logged there: refused before the diagnosis
            check_log(site_dir)
            probes = [sim.as_sent(p, site_policy.withheld)
                      for p in site_signatures(Path(target), site_policy, acceptance, unkept, skipped, stored=False)]
            sim.log_probes(site_dir, probes, site_policy, st.where)
        else:
            probes = [sim.probe_of(st, target)]
        out = [{"cause": p.cause, "neighbours": [n.to_dict() for n in sim.similar(st, p, limit)]} for p in probes]
    except CellguardError as exc:
        fail(exc)
    if as_json:
        sys.stdout.write(json.dumps({"findings": out}) + "\n")
    else:
        for f in out:
            say(f"finding {f['cause']}: {len(f['neighbours'])} similar signature(s)", err=False)
            for n in f["neighbours"]:
                fixes = "; ".join(f"{x['recovery'] or 'no recovery recorded'} fixed {x['fixed']}/{x['signatures']} "
                                  f"({x['scope']})" for x in n["fixes"]) or "no fix known"
                say(f"  {n['similarity']:.3f} {n['cause']} at site {n['site_id']} ({n['robot_model']}): {fixes}",
                    err=False)
    if max(warn_if_unkept(unkept), _warn_if_skipped(skipped)):
        raise typer.Exit(1)


@fleet_app.command()
def audit(site_dir: Path = SITE_DIR, as_json: bool = JSON) -> None:
    """This site's audit log: every export, when, how many rows, under which policy version, where to. A damaged
    line is named on stderr and the others shown (exit 1); a log that is a link is refused (exit 2)."""
    from cellguard.fleet.audit import scan_audit

    try:
        entries, damaged = scan_audit(site_dir)
    except CellguardError as exc:
        fail(exc)
    if as_json:
        sys.stdout.write(json.dumps({"entries": entries, "damaged": damaged}) + "\n")
    else:
        say(f"audit log of {site_dir}: {len(entries)} entr{'y' if len(entries) == 1 else 'ies'}", err=False)
        for e in entries:
            why = f" ({e['reason']})" if e.get("reason") else ""
            if e.get("policy_in_force") not in (None, e["policy_version"]):
                why = f" in_force={e['policy_in_force']}{why}"
            say(f"  {e['when_utc']} {e['status']:<9} {e['what']:<15} rows={e['rows']} kept={e['withheld_rows']} "
                f"policy={e['policy_version']} batch={e['batch_id'][:12]}{_where(e)}{why}", err=False)
    for line in damaged:
        sys.stderr.write(f"warning: {printable(Path(site_dir) / 'audit.jsonl')}: {printable(line)}; not shown\n")
    if damaged:
        raise typer.Exit(1)


STAYS = ("queued", "held", "refused")  # the statuses of a batch that is in the outbox
DELETED = ("retention", "withdrawn")  # the statuses of rows deleted, not sent


def _where(entry: dict) -> str:
    """`` to=``/`` from=`` the place an audit entry's rows went to or were deleted from (a batch that waits: the
    outbox, for the store it waits for); nothing for an entry logged without it or for an export of nothing."""
    from cellguard.fleet.audit import destination_of

    where = destination_of(entry)
    if where is None or entry["status"] == "nothing":
        return ""
    if entry["status"] in STAYS:
        return " to=outbox" + ("" if where == "nowhere" else f" for {where}")
    return f" {'from' if entry['status'] in DELETED else 'to'}={where}"


@fleet_app.command()
def withdraw(
    policy: Path = typer.Option(..., "--policy", help="The site's data policy (it names the tenant and site)."),
    store: str | None = STORE,
    lake: Path | None = typer.Option(None, "--lake", help="Also take the site's signatures out of this lake."),
    site_dir: Path = SITE_DIR,
    as_json: bool = JSON,
) -> None:
    """Delete every signature and aggregate this site pooled, from the lake and the store (as this tenant):
    a customer withdrawing its consent. What waits in the outbox stays at the site (set ``export: nothing``
    to keep it there). The lake goes first: it reads every file of the tenant's before it changes one, so
    a lake it cannot read leaves both as they were; a store that then fails is named with what the lake
    gave up. Each deletion is logged in the audit log of --site-dir (status withdrawn, its rows and where), so
    --site-dir must be the site's folder: one that is not a folder is refused before anything is deleted. Once
    the store holds nothing of the site, a --site-dir with no site key gets one: a push from there (refused while
    batches sent without the key were in the store) stores nothing twice."""
    from cellguard.errors import ConfigError
    from cellguard.fleet.audit import append_withdrawal
    from cellguard.fleet.lake import check_lake, forget
    from cellguard.fleet.policy import load_policy
    from cellguard.fleet.push import check_site

    in_lake = in_store = None
    try:
        pol = load_policy(policy, sends=False)
        tenant_store = _store(store)
        if tenant_store is None and lake is None:
            raise ConfigError("--store: no fleet store DSN (or CELLGUARD_FLEET_DSN); or give --lake")
        check_site(site_dir, must_exist=True)
        as_tenant = _store_tenant(tenant_store, pol.tenant) if tenant_store is not None else None
        if lake is not None:
            in_lake = forget(check_lake(lake), pol.tenant, pol.site)
            append_withdrawal(site_dir, pol, in_lake, str(lake))
        if tenant_store is not None:
            in_store = tenant_store.forget(pol.site)
            append_withdrawal(site_dir, pol, in_store, tenant_store.where, store_tenant=as_tenant)
        stdout.written(f"the withdrawal of site {pol.site} ({in_store or 0} row(s) from the store, {in_lake or 0} "
                       f"signature(s) from the lake) in the audit log of {site_dir}")
    except CellguardError as exc:
        if in_lake is not None or in_store is not None:
            exc = _withdrawn_so_far(exc, pol.site, in_lake, in_store, tenant_store is not None)
        fail(exc)
    if tenant_store is not None:
        _key_after_withdrawal(site_dir)
    if as_json:
        sys.stdout.write(json.dumps({"tenant": pol.tenant, "site": pol.site, "store_rows": in_store or 0,
                                     "lake_signatures": in_lake or 0}) + "\n")
    else:
        say(f"fleet withdraw: site {pol.site} of {pol.tenant}: {in_store or 0} row(s) deleted from the store, "
            f"{in_lake or 0} signature(s) from the lake", err=False)


def _store_tenant(tenant_store, tenant: str) -> str:
    """``tenant`` if the store's credentials log in as it, else ConfigError before anything is deleted: as another
    tenant the store deletes none of its rows, and the withdrawal would be logged as done."""
    from cellguard.errors import ConfigError

    as_tenant = tenant_store.tenant()
    if as_tenant != tenant:
        raise ConfigError(f"--store: its credentials are {f'tenant {as_tenant}' if as_tenant else 'no tenant'}'s, "
                          f"the policy's tenant is {tenant}: nothing withdrawn; give the store credentials of "
                          f"tenant {tenant}")
    return as_tenant


def _withdrawn_so_far(exc: CellguardError, site: str, in_lake: int | None, in_store: int | None,
                      to_store: bool) -> CellguardError:
    """``exc``, saying what the withdrawal deleted before it (a deletion cannot be undone) and what it did not."""
    gone = " and ".join(f"{n} {what}" for n, what in ((in_lake, "signature(s) from the lake"),
                                                      (in_store, "row(s) from the store")) if n is not None)
    left = "; not the store's: run fleet withdraw again" if to_store and in_store is None else ""
    return CellguardError(f"{exc}; deleted already: {gone} of site {site}{left}")


def _key_after_withdrawal(site_dir: Path) -> None:
    """Make the site key of ``site_dir`` if it has none (noted): the site's rows are gone from the store, so ids
    keyed from now on repeat nothing there (``push.check_key_history``)."""
    from cellguard.fleet.site_key import KEY_FILE, make_key, site_key

    try:
        made = make_key(site_dir)
        if made:  # a key already there is the push's to check: the withdrawal's summary is not held up by it
            site_key(site_dir)
    except CellguardError as exc:
        fail(exc)
    if made:
        _new_key_note(str(Path(site_dir) / KEY_FILE))
