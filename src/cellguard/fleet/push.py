"""One push from a site: queued batches first, then this one; whatever cannot be sent waits.

Order of work, so that nothing is lost: the batch is built under the policy, written to the
outbox, logged in the audit log, and only then is the store asked for anything; a batch leaves the
outbox only once the store has taken it. A store that is down, or never answers and the push is
interrupted, leaves every batch queued for the next push.

Each queued batch is sent only if the policy in force now allows it (``export.refusal``): the
policy it was built under may have been replaced since it was queued. One the policy no longer
allows is **held**: not sent, logged ``held`` with the reason, kept in the outbox (logged once for
the same policy and reason, not again at every push). Held, not rebuilt under the new policy and not deleted, because:

- the customer's policy in force is their current word on what may leave the site, and a batch
  still at the site has not left yet: sending it under the policy it was made with would send
  what the customer has since forbidden (``export: nothing`` sending signatures);
- rebuilding it would send rows no export of the site's records produced (withholding more
  fields from rows already cut, counting aggregates over a batch, not over the records), and
  the next push of the run folders exports them under the policy in force anyway;
- deleting it could lose the only copy of what the site recorded (its runs may be gone); held,
  it goes if the customer restores a policy that allows it, or a person deletes the file.

Signatures of a queued batch that have passed the retention of the policy in force since it was queued (a store
down for days, a retention shortened) are dropped, never sent, and the rest of the batch is sent
(``export.within_retention``): logged ``sent`` with the count dropped and ``trimmed_from`` the queued batch, said
in one line. Held whole for them, its rows within the retention were held with it for good, as time only makes more
rows old. A batch with every signature past the retention, or a batch of counts (sent late, a month's older count
would replace a newer one), is held whole (a policy that keeps rows longer lets it go).

A queued batch the store refuses (another tenant's, say) or a file that cannot be read stays
queued too, named in one line; the other batches go on. With ``lake``, a batch is staged in the lake
before the store commits it and made visible only once the commit succeeded (``landing.Landing``): a lake
that cannot take it leaves the store as it was, and the batch queued; one the store refuses at its commit
leaves the lake as it was. What a push left staged (the store lost mid-commit, the push killed) is brought
to what the store holds by the next push that reaches it. A folder whose audit log names another site
(or tenant) the store took batches of is refused (``check_same_site``): the same findings would be stored
again under the new id.

What the export keeps and what a queued batch may take out are counted on the store's UTC date, as its retention
is: the batch is built and queued on this host's date (the order above), and once the store's date is read and is
within a day of it, recounted on the store's, replacing the queued file where that changes it (the audit says so):
around midnight UTC, or with a host a day slow, a row the store's retention had just deleted was sent again. When
the two dates are more than a day apart (``_distrust``) one of the clocks is wrong and nothing says which, so the
push sends nothing (every batch stays queued) and its retention deletes nothing, in one warning line naming both
dates: a store a year slow let a 400-day-old signature past a 365-day retention leave; a store, or a host, a year
fast kept every fresh signature at the site and held batches queued with a right clock. The next push with the
clocks agreeing sends what is queued. The signatures the export keeps at the site as dated after tomorrow, by the
date it counted on, are named in one line (``_kept_ahead``): with a host a day ahead of the store, one dated the
host's tomorrow passed the run's check (``from_record``, by the host's date) and was kept back unsaid.

Every push applies the policy's retention to the store (when it can be reached) and to ``lake``:
the site's signatures older than ``retention_days`` and its aggregates of the months before are
deleted, whatever is sent, even nothing; the rows deleted are counted and logged. The days are
counted on the store's clock (in its SQL), and a deletion cannot be undone, so this host's date is
checked before anything goes: more than a day off the store's (then nothing is sent either, above), or, with no
store to ask, more than the retention after the site's newest signature (it would delete them all: a clock a year
fast), retention deletes nothing this push and says so in one line naming the dates.

A site folder with no site key whose audit log says a store took batches of the site (sent before the key, or
under a key since lost) is refused before anything is made: a new key gave the
same findings new ids, stored a second time. ``fleet withdraw`` deletes what the site pooled and makes the key; then
the site pushes again. So is a ``site_dir`` that is not a folder (a file there ended the push in a traceback, after
the diagnosis), or whose audit log (a hard link too), site key or outbox is a link (``check_site``), and a link in
the outbox where the batch is to be queued (``Outbox.put``): the site's files are written only in its folder, never
through a link (a link to nothing took the audit log outside the site).
"""

from __future__ import annotations

import datetime as dt
from collections import defaultdict
from dataclasses import dataclass
from functools import partial
from pathlib import Path

from cellguard.dates import utc_today
from cellguard.errors import ConfigError, OutputError
from cellguard.fleet.audit import (append_audit, append_retention, check_log, check_site_dir, destination_of,
                                   refuse_links, scan_audit)
from cellguard.fleet.export import (AHEAD, Batch, dated_ahead, export_batch, newest_kept, oldest_kept, refusal,
                                    within_retention)
from cellguard.fleet.lake import check_lake, forget, newest
from cellguard.fleet.landing import Unpublished, reconcile, stage_signatures
from cellguard.fleet.outbox import OUTBOX, Outbox
from cellguard.fleet.policy import DataPolicy
from cellguard.fleet.signature import Signature
from cellguard.fleet.site_key import KEY_FILE, fingerprint, make_key, site_key
from cellguard.fleet.store import StoreError, StoreUnavailable, TenantStore


@dataclass(frozen=True)
class PushResult:
    batch: Batch
    sent_batches: int  # this one and earlier queued ones
    new_rows: int
    duplicate_rows: int
    queued: int  # batches still in the outbox
    unavailable: str | None = None  # why the store could not be reached
    held: tuple[str, ...] = ()  # one line per queued batch the policy in force keeps at the site
    failed: tuple[str, ...] = ()  # one line per queued file that cannot be read or that the store refused
    new_key: str | None = None  # the site key this push made (ids of this site's earlier pushes differ)
    retention_removed: int = 0  # rows the policy's retention deleted from the store and the lake
    dated_ahead: str | None = None  # one line: the signatures the export kept at the site as dated after tomorrow
    trimmed: tuple[str, ...] = ()  # one line per queued batch sent without its rows past the retention

    def to_dict(self) -> dict:
        return {"batch_id": self.batch.batch_id, "export": self.batch.export, "rows": self.batch.rows,
                "withheld_rows": self.batch.withheld_rows, "policy_version": self.batch.policy_version,
                "sent_batches": self.sent_batches, "new_rows": self.new_rows, "duplicate_rows": self.duplicate_rows,
                "queued": self.queued, "unavailable": self.unavailable, "held": list(self.held),
                "failed": list(self.failed), "new_key": self.new_key, "retention_removed": self.retention_removed,
                "dated_ahead": self.dated_ahead, "trimmed": list(self.trimmed)}


def push(signatures: list[Signature], policy: DataPolicy, site_dir: Path, store: TenantStore | None,
         lake: Path | None = None, today: dt.date | None = None) -> PushResult:
    """Export ``signatures`` under ``policy`` and send them (and any queued batch it allows) to ``store``;
    ``today``: this host's UTC date (default: its clock's)."""
    if lake is not None:
        check_lake(lake)  # before anything is queued or sent
    check_site(site_dir)
    check_history(site_dir, policy)
    made = str(Path(site_dir) / KEY_FILE) if make_key(site_dir) else None
    key = site_key(site_dir)
    local = today or utc_today()
    batch = export_batch(signatures, policy, local, key=key)
    outbox = Outbox(site_dir)
    destination = store.where if store is not None else "nowhere"
    mine = _queue(batch, outbox, site_dir, destination, local)
    server, unavailable = _store_date(store)  # only now: a store that never answers leaves the batch queued
    if server is not None and server != local and abs((server - local).days) <= 1:
        local = server  # within a day: counted on the store's date, as its retention is (around midnight UTC too)
        again = export_batch(signatures, policy, local, key=key)
        if again.batch_id != batch.batch_id:
            if mine is not None:
                outbox.done(mine)
            _queue(again, outbox, site_dir, destination, local, reason=f"recounted on the store's date: replaces "
                                                                          f"batch {batch.batch_id}")
            batch = again
    ahead = _kept_ahead(signatures, policy, local, "the fleet store" if local == server else "this host")
    queued, unreadable = outbox.read()
    failed = [f"{path}: {why}; it stays queued" for path, why in unreadable]
    held: list[str] = []
    trimmed: list[str] = []
    sent = new = dup = 0
    removed, lost, doubt = _apply_retention(policy, site_dir, store, lake, local, server, failed)
    unavailable = unavailable or lost
    if lake is not None and server is not None and unavailable is None:
        unavailable = _reconcile_lake(lake, policy.tenant, store, failed)
    if doubt:
        sends = f"nothing is sent ({len(queued)} batch(es) stay queued) and " if server is not None else ""
        failed.append(f"{doubt}: {sends}the retention of {policy.retention_days} days deletes nothing this push")
    sending = server is not None and not doubt and unavailable is None
    last = _last_entries(site_dir) if queued and sending else {}
    for path, waiting in queued if sending else ():
        going, past = within_retention(waiting, policy, local)
        why = refusal(going, policy, local)
        unkeyed = _unkeyed(going, key) if why is None else None
        if why is not None or unkeyed is not None:
            said = last.get(waiting.batch_id, {})
            reason = why or unkeyed
            if (said.get("status"), said.get("reason"), said.get("policy_in_force")) != ("held", reason, policy.version):
                append_audit(site_dir, waiting, "held", destination, reason=reason, policy_in_force=policy.version)
            held.append(f"{path}: held at the site, " + (f"the policy in force ({policy.version}) does not allow it: "
                                                         f"{why}" if why else unkeyed))
            continue
        land = partial(stage_signatures, lake, going.signatures, going.batch_id) if lake is not None else None
        try:
            n, d = store.push(going, stage=land)
        except StoreUnavailable as exc:
            unavailable = str(exc)
            break
        except StoreError as exc:
            append_audit(site_dir, waiting, "refused", destination, reason=str(exc), policy_in_force=policy.version)
            failed.append(f"{path}: {exc}; it stays queued")
            continue
        except Unpublished as exc:  # the store took it: sent, the lake catches up on the next push
            failed.append(str(exc))
            n, d = exc.taken
        except OutputError as exc:  # the lake could not take it: the store rolled back
            failed.append(f"{path}: {exc}; it stays queued")
            continue
        outbox.done(path)
        left = {"reason": f"the rest of batch {waiting.batch_id}: {past} row(s) older than the policy's "
                          f"retention_days ({policy.retention_days}) not sent, dropped",
                "trimmed_from": waiting.batch_id} if past else {}
        append_audit(site_dir, going, "sent" if n else "duplicate", destination, policy_in_force=policy.version, **left)
        if past:
            trimmed.append(f"{path}: {left['reason']}")
        sent, new, dup = sent + 1, new + n, dup + d
    return PushResult(batch, sent, new, dup, outbox.count(), unavailable, tuple(held), tuple(failed), made, removed,
                      ahead, tuple(trimmed))


def check_site(site_dir: Path, must_exist: bool = False) -> None:
    """ConfigError, before anything is made, sent or deleted, for a ``site_dir`` that is not a folder (nor, unless
    ``must_exist``, missing: a push makes it) or whose audit log (``check_log``: a hard link too), site key or outbox
    is a link."""
    check_site_dir(site_dir, missing_ok=not must_exist)
    check_log(site_dir)
    refuse_links(site_dir, KEY_FILE, OUTBOX)


def check_history(site_dir: Path, policy: DataPolicy) -> None:
    """ConfigError if the audit log of ``site_dir`` says a push of ``policy`` would store findings a second time
    (``check_key_history``, ``check_same_site``)."""
    check_key_history(site_dir, policy)
    check_same_site(site_dir, policy)


def check_same_site(site_dir: Path, policy: DataPolicy) -> None:
    """ConfigError if the audit log says batches of another tenant or site went to a store from ``site_dir`` and were
    not withdrawn from it since (by a withdrawal logged as made with that tenant's store credentials: another
    tenant's delete none of its rows). The site key and the runs are the folder's, so the same findings would be stored
    again under the policy's new ids (a site renamed in the policy counted each cause at two sites). Refused, not
    renamed: a withdrawal cannot be undone, and a policy copied from another site should not delete this one's rows."""
    site_dir = Path(site_dir)
    if not site_dir.is_dir():
        return
    stored: dict[tuple[str, str], set[str | None]] = defaultdict(set)
    for e in scan_audit(site_dir)[0]:
        was = (e.get("tenant_id"), e.get("site_id"))
        if None in was or was == (policy.tenant, policy.site):
            continue
        if e["status"] in ("sent", "duplicate"):
            stored[was].add(destination_of(e))
        elif e["status"] == "withdrawn" and e.get("store_tenant") == was[0]:  # deleted as that tenant: really gone
            stored[was].discard(destination_of(e))
    for (tenant, site), where in sorted(stored.items()):
        if where:
            raise ConfigError(
                f"--site-dir {site_dir}: batches of site {site} (tenant {tenant}) went to {sorted(map(str, where))[0]} "
                f"from here, but the policy names site {policy.site} (tenant {policy.tenant}); with this folder's "
                f"key and runs a push would store every finding again under the new id: to rename the site, run "
                f"`cellguard fleet withdraw --policy OLD_POLICY --store OLD_DSN --site-dir {site_dir}` (with --lake "
                f"if they landed in one) with the old policy naming {site} and the store credentials of tenant "
                f"{tenant}, then push; for another site, give it a new --site-dir")


def check_key_history(site_dir: Path, policy: DataPolicy) -> None:
    """ConfigError if ``site_dir`` has no site key but its audit log says a store took batches of this site: sent
    by a version before the key, or under a key since lost. A new key gives their findings new ids, so the push
    stored each of them a second time (and ids made before the key keep withheld fields recoverable); withdrawing
    the site first deletes them, and makes the key (``fleet withdraw``). An earlier withdrawal clears nothing: the
    log names a store by host, port and database, which two stores can share (a ``service=`` DSN, defaults from the
    environment), so a withdrawal from one let the other's batches be stored twice."""
    site_dir = Path(site_dir)
    if (site_dir / KEY_FILE).exists() or not site_dir.is_dir():
        return
    taken = {e["batch_id"] for e in scan_audit(site_dir)[0] if e["status"] in ("sent", "duplicate")
             and (e.get("tenant_id"), e.get("site_id")) == (policy.tenant, policy.site)}
    if taken:
        raise ConfigError(f"--site-dir {site_dir}: no site key ({KEY_FILE}), but {len(taken)} batch(es) of site "
                          f"{policy.site} went to the store from here without it; a push would store their findings "
                          f"again under new ids: run `cellguard fleet withdraw --policy POLICY --site-dir {site_dir}` "
                          f"once (with --lake if they landed in one), then push again")


def _kept_ahead(signatures: list[Signature], policy: DataPolicy, counted_on: dt.date, clock: str) -> str | None:
    """One line naming the signatures the export kept at the site as dated after tomorrow by ``counted_on`` (the
    UTC date of ``clock``), or None. Counted on the store's date, a record dated by a host a day ahead of it passed
    that host's own check (``from_record``), and the push said only "kept at the site"."""
    days = dated_ahead(signatures, counted_on) if policy.export != "nothing" else []
    if not days:
        return None
    span = days[0] if days[0] == days[-1] else f"{days[0]} to {days[-1]}"
    return (f"{len(days)} signature(s) dated {span} kept at the site: after tomorrow ({newest_kept(counted_on)}) by "
            f"{clock}'s UTC date (the clock that recorded them ran ahead, or {clock}'s clock is behind): {AHEAD}")


def _unkeyed(batch: Batch, key: bytes) -> str | None:
    """Why a queued batch's signature ids may not leave: made without this site's key (queued by a version before
    the key, or under a key since replaced), they are hashes from which withheld fields can be recovered."""
    if not batch.signatures or batch.key_id == fingerprint(key):
        return None
    return ("its signature ids were not made with this site's key (queued before it existed, or under another): "
            "push the runs again, which exports them keyed, then delete this file")


def _queue(batch: Batch, outbox: Outbox, site_dir: Path, destination: str, counted_on: dt.date,
           **more: str) -> Path | None:
    """Queue ``batch`` and log it (or log that it holds nothing); its outbox file, or None."""
    counted = {"retention_counted_on": counted_on.isoformat(), **more}
    if batch.export == "nothing" or batch.rows == 0:
        append_audit(site_dir, batch, "nothing", destination, **counted)
        return None
    path = outbox.put(batch)
    append_audit(site_dir, batch, "queued", destination, **counted)
    return path


def _store_date(store: TenantStore | None) -> tuple[dt.date | None, str | None]:
    """(the store's UTC date, or None with no store; why it could not be reached, or None)."""
    try:
        return (store.today() if store is not None else None), None
    except StoreUnavailable as exc:
        return None, str(exc)


def _apply_retention(policy: DataPolicy, site_dir: Path, store: TenantStore | None, lake: Path | None,
                     local: dt.date, server: dt.date | None, failed: list[str]) -> tuple[int, str | None, str | None]:
    """Delete the site's rows past the policy's retention from the store (when its date ``server`` was read) and
    ``lake``, logging each deletion and adding a line to ``failed`` for each place that refused; (rows deleted,
    why the store was lost meanwhile, or None; why the host date ``local`` cannot be trusted (``_distrust``), or
    None: then nothing is deleted, each place's log entry says why, and the caller says so)."""
    before = oldest_kept(policy, server or local)
    places = [(str(lake), partial(forget, lake, policy.tenant, policy.site, before))] if lake is not None else []
    if server is not None:
        places.append((store.where, partial(store.forget, policy.site, policy.retention_days)))
    removed = 0
    try:
        doubt = _distrust(local, server, policy, lake) if places else None
    except OutputError as exc:  # a lake file that cannot be read: the lake's forget would refuse it too
        places, doubt = [], None
        failed.append(f"{exc}; the retention of {policy.retention_days} days is not applied there")
    if doubt:
        for where, _ in places:
            append_retention(site_dir, policy, 0, where, reason=doubt)
        return 0, None, doubt
    for where, forget_older in places:
        try:
            n = forget_older()
        except StoreUnavailable as exc:
            return removed, str(exc), None
        except (OutputError, StoreError) as exc:
            failed.append(f"{exc}; the retention of {policy.retention_days} days is not applied there")
            continue
        if n:
            append_retention(site_dir, policy, n, where, before=before.isoformat())
        removed += n
    return removed, None, None


def _reconcile_lake(lake: Path, tenant: str, store: TenantStore, failed: list[str]) -> str | None:
    """Bring what earlier pushes left staged in ``lake`` (the store lost mid-commit, a push killed) to what
    ``store`` holds (``landing.reconcile``), adding a line to ``failed`` where the lake refuses and one per staged
    file it leaves (no locks, unreadable); why the store was lost meanwhile, or None."""
    try:
        failed.extend(reconcile(lake, tenant, store.held)[1])
    except StoreUnavailable as exc:
        return str(exc)
    except (OutputError, StoreError) as exc:
        failed.append(f"{exc}; what earlier pushes left staged in the lake stays staged")
    return None


def _distrust(local: dt.date, server: dt.date | None, policy: DataPolicy, lake: Path | None) -> str | None:
    """Why this host's date ``local`` is not one to delete by, or None: more than a day off the store's
    (``server``: then one of the two clocks is wrong, and nothing is sent by either date either); with no store to
    ask, later than the site's newest signature already in ``lake`` by more than the
    retention, which would delete every one of them (a clock set a year fast, not a year without a finding, is the
    likely cause; the next push with a right clock deletes what is due). This push's own signatures are no
    witness: a clock that ran fast while they were recorded dates them as fast (counted, a year-fast clock with
    the store down emptied the lake, exit 0)."""
    if server is not None:
        off = abs((local - server).days)
        return f"this host's date {local} is {off} days off the fleet store's {server}" if off > 1 else None
    last = newest(lake, policy.tenant, policy.site) if lake is not None else None
    if last is not None and last < oldest_kept(policy, local):
        return (f"this host's date {local} is more than the retention after the site's newest signature ({last}), "
                f"and would delete every one")
    return None


def _last_entries(site_dir: Path) -> dict[str, dict]:
    """Each batch's last audit entry (a damaged line is skipped: it is named by ``fleet audit``)."""
    return {entry["batch_id"]: entry for entry in scan_audit(site_dir)[0]}
