"""Enforcing a data policy at export: from a site's signatures to the batch that may leave it.

``signatures``: each signature with the withheld fields emptied, under an id keyed with the site's
secret (``site_key.py``); ``aggregates_only``: counts per (cause, robot model, cell type, month), a
withheld robot model or cell type left out of the grouping (null), a count over fewer than
``min_group_size`` signatures not sent;
``nothing``: an empty batch. Signatures past the retention period are never sent, nor those dated after
tomorrow (``newest_kept``). The batch is all that leaves the site: it holds no record, no tick and no raw
feature value. A batch that waited in the outbox is checked again against the policy in force when it is to
leave (``refusal``; ``push.py`` says what happens to one it no longer allows).
"""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import re
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

from cellguard.dates import utc_today
from cellguard.fleet.policy import EXPORTS, DataPolicy, PolicyError
from cellguard.fleet.signature import Signature, SignatureError, check_text, row_from_dict, withhold
from cellguard.fleet.site_key import fingerprint


@dataclass(frozen=True)
class Batch:
    """What one push sends: rows under one policy version; ``batch_id`` is its content hash."""

    tenant_id: str
    site_id: str
    policy_version: str
    export: str
    signatures: tuple[dict, ...] = ()
    aggregates: tuple[dict, ...] = ()
    withheld_rows: int = 0  # signatures kept at the site (too few, too old, dated ahead, or the policy's nothing)
    key_id: str | None = None  # the site key its signature ids were made with (``site_key.fingerprint``)

    def __post_init__(self):
        for i, s in enumerate(self.signatures):  # the batch's tenant and site are what the policy checks
            if (s["tenant_id"], s["site_id"]) != (self.tenant_id, self.site_id):
                raise SignatureError(f"batch.signatures[{i}]: of {s['tenant_id']}/{s['site_id']}, in a batch of "
                                     f"{self.tenant_id}/{self.site_id}")

    @property
    def rows(self) -> int:
        return len(self.signatures) + len(self.aggregates)

    @property
    def batch_id(self) -> str:
        body = json.dumps(self.to_dict(with_id=False), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(body.encode()).hexdigest()[:32]

    def to_dict(self, with_id: bool = True) -> dict:
        out = {"tenant_id": self.tenant_id, "site_id": self.site_id, "policy_version": self.policy_version,
               "export": self.export, "signatures": list(self.signatures), "aggregates": list(self.aggregates),
               "withheld_rows": self.withheld_rows, **({"key_id": self.key_id} if self.key_id else {})}
        return {"batch_id": self.batch_id, **out} if with_id else out

    @classmethod
    def from_dict(cls, raw: object) -> Batch:
        """A batch from its JSON; a missing or mistyped field raises SignatureError naming it, and each
        signature is read as one (a newer schema version, an unknown field, a quoted or non-finite
        number, text with control characters, another site's signature are refused)."""
        if not isinstance(raw, Mapping):
            raise SignatureError(f"batch: expected a JSON object, got {type(raw).__name__}")
        for key in ("tenant_id", "site_id", "policy_version", "export"):
            if not isinstance(raw.get(key), str):
                raise SignatureError(f"batch.{key}: required text, got {raw.get(key)!r}")
        check_text(raw["policy_version"], "batch.policy_version", required=True)
        if raw["export"] not in EXPORTS:
            raise SignatureError(f"batch.export: {raw['export']!r}; allowed: {', '.join(EXPORTS)}")
        for key in ("signatures", "aggregates"):
            if not isinstance(raw.get(key), list):
                raise SignatureError(f"batch.{key}: expected a list, got {type(raw.get(key)).__name__}")
        withheld = raw.get("withheld_rows", 0)
        if isinstance(withheld, bool) or not isinstance(withheld, int) or withheld < 0:
            raise SignatureError(f"batch.withheld_rows: expected a count, got {withheld!r}")
        key_id = raw.get("key_id")
        if key_id is not None and not (isinstance(key_id, str) and re.fullmatch(r"[0-9a-f]{16}", key_id)):
            raise SignatureError(f"batch.key_id: expected 16 hex digits, got {key_id!r}")
        batch = cls(raw["tenant_id"], raw["site_id"], raw["policy_version"], raw["export"],
                    tuple(row_from_dict(s) for s in raw["signatures"]),
                    tuple(_aggregate(r) for r in raw["aggregates"]), withheld, key_id)
        if "batch_id" in raw and raw["batch_id"] != batch.batch_id:
            raise SignatureError(f"batch.batch_id: {raw['batch_id']!r} does not match its content")
        return batch


AGGREGATE_KEYS = ("cause", "robot_model", "cell_type", "month", "signatures")


def _aggregate(raw: object) -> dict:
    """One aggregate row as ``export_batch`` writes it, or SignatureError naming what is wrong."""
    if not isinstance(raw, Mapping) or sorted(raw) != sorted(AGGREGATE_KEYS):
        got = sorted(raw) if isinstance(raw, Mapping) else type(raw).__name__
        raise SignatureError(f"batch.aggregates: expected rows with keys {', '.join(AGGREGATE_KEYS)}, got {got}")
    for key in ("cause", "robot_model", "cell_type"):
        check_text(raw[key], f"batch.aggregates.{key}", required=key == "cause")
    if not isinstance(raw["month"], str) or not re.fullmatch(r"[0-9]{4}-[0-9]{2}", raw["month"]):
        raise SignatureError(f"batch.aggregates.month: expected YYYY-MM, got {raw['month']!r}")
    n = raw["signatures"]
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise SignatureError(f"batch.aggregates.signatures: expected a count, got {n!r}")
    return dict(raw)


def refusal(batch: Batch, policy: DataPolicy, today: dt.date | None = None) -> str | None:
    """Why ``policy`` (the one in force now) does not let ``batch`` leave the site, or None if it does.

    A batch waits in the outbox under the policy it was built with; the customer may have changed
    the policy since. What leaves is decided when it leaves: the batch goes only if it shows
    nothing the policy in force keeps at the site (another tenant or site, a form of export it
    no longer allows, a field it withholds, a row past its retention or dated after tomorrow, a count
    under its group size). Aggregates may go under a policy that allows signatures (they say less).
    """
    if (batch.tenant_id, batch.site_id) != (policy.tenant, policy.site):
        return f"it is {batch.tenant_id}/{batch.site_id}'s, the policy is {policy.tenant}/{policy.site}'s"
    if batch.rows == 0:
        return None
    if policy.export == "nothing":
        return "the policy exports nothing"
    if batch.signatures and policy.export != "signatures":
        return f"it holds signatures, the policy exports {policy.export}"
    rows = (*batch.signatures, *batch.aggregates)
    shown = sorted({n for r in rows for n in policy.withheld if r.get(n) not in (None, {})})
    if shown:
        return f"it holds {', '.join(shown)}, which the policy withholds"
    today = today or utc_today()
    oldest, newest = oldest_kept(policy, today).isoformat(), newest_kept(today).isoformat()
    dates = [(s["created_date"], 10) for s in batch.signatures] + [(r["month"], 7) for r in batch.aggregates]
    old = sum(d < oldest[:n] for d, n in dates)  # ISO dates and months: in order as text
    if old:
        return f"{old} row(s) older than the policy's retention_days ({policy.retention_days})"
    ahead = sum(d > newest[:n] for d, n in dates)
    if ahead:
        return f"{ahead} row(s) dated after tomorrow ({newest}) by a clock that ran ahead: {AHEAD}"
    if policy.export == "aggregates_only":
        small = sum(r["signatures"] < policy.min_group_size for r in batch.aggregates)
        if small:
            return f"{small} count(s) under the policy's min_group_size ({policy.min_group_size})"
    return None


def within_retention(batch: Batch, policy: DataPolicy, today: dt.date) -> tuple[Batch, int]:
    """(``batch`` without its signatures past ``policy``'s retention by ``today``, how many that leaves out). A batch
    queued while the store was down reaches the retention's edge row by row: held whole for one row past it, its
    rows within were held with it for good (time only makes more of them old). Each row left is as the export
    wrote it, and the store's retention deletes the ones left out at this push anyway. Counts (aggregates) are never
    trimmed: a month's count replaces the store's, so an older batch's counts sent after a newer one's (held for
    another reason meanwhile) would put back the older figures; such a batch, like one with every signature past
    the retention, is returned whole (``refusal`` holds it, and a policy that keeps rows longer lets it go)."""
    oldest = oldest_kept(policy, today).isoformat()
    signatures = tuple(s for s in batch.signatures if s["created_date"] >= oldest)  # ISO dates: text order
    out = len(batch.signatures) - len(signatures)
    if out == 0 or not signatures or batch.aggregates:
        return batch, 0
    return replace(batch, signatures=signatures, withheld_rows=batch.withheld_rows + out), out


def oldest_kept(policy: DataPolicy, today: dt.date | None = None) -> dt.date:
    """The first day the policy's retention keeps, counted from ``today`` (default: this host's UTC date)."""
    return (today or utc_today()) - dt.timedelta(days=policy.retention_days)


AHEAD = "the retention counts from that date, so it would keep them past it"


def newest_kept(today: dt.date | None = None) -> dt.date:
    """The last day a row may be dated and leave the site: tomorrow by ``today`` (default: this host's UTC date),
    the day the host's and the store's dates may differ by. A record dated later was stamped by a clock that ran
    ahead: sent, its row outlived the retention (dated a year ahead, it stayed a year past it)."""
    return (today or utc_today()) + dt.timedelta(days=1)


def dated_ahead(signatures: Sequence[Signature], today: dt.date) -> list[str]:
    """The dates, in order, of the ``signatures`` that ``export_batch`` keeps at the site as dated after tomorrow by
    ``today`` (``newest_kept``)."""
    newest = newest_kept(today)
    return sorted(s.created_date for s in signatures if dt.date.fromisoformat(s.created_date) > newest)


def export_batch(signatures: Sequence[Signature], policy: DataPolicy, today: dt.date | None = None, *,
                 key: bytes) -> Batch:
    """The batch ``policy`` lets leave the site, from the site's ``signatures``; ``key`` is the site's
    secret the signature ids are keyed with; ``today``: the date retention counts from, whose tomorrow is the
    latest a signature sent may be dated (default: this host's UTC date). A signature of another tenant or site,
    whatever its date, is refused (PolicyError): it is not this site's to send, to count, or to say it kept. Two runs
    of one finding count twice (the same finding of two runs is two findings); a record held twice in the runs
    folder is read once (``from_record.site_signatures``)."""
    for s in signatures:
        if (s.tenant_id, s.site_id) != (policy.tenant, policy.site):
            raise PolicyError(f"signature.tenant_id/site_id: {s.tenant_id}/{s.site_id} is not the policy's "
                              f"{policy.tenant}/{policy.site}")
    today = today or utc_today()
    oldest, newest = oldest_kept(policy, today), newest_kept(today)
    live = [s for s in signatures if oldest <= dt.date.fromisoformat(s.created_date) <= newest]
    base = dict(tenant_id=policy.tenant, site_id=policy.site, policy_version=policy.version, export=policy.export)
    if policy.export == "nothing":
        return Batch(**base, withheld_rows=len(signatures))
    if policy.export == "aggregates_only":
        hide = policy.withheld  # a withheld robot model or cell type is not a group: one row over all of them
        counts = Counter((s.cause, None if "robot_model" in hide else s.robot_model,
                          None if "cell_type" in hide else s.cell_type, s.created_date[:7]) for s in live)
        rows = tuple({"cause": c, "robot_model": m, "cell_type": t, "month": mo, "signatures": n}
                     for (c, m, t, mo), n in sorted(counts.items(), key=str) if n >= policy.min_group_size)
        sent = sum(r["signatures"] for r in rows)
        return Batch(**base, aggregates=rows, withheld_rows=len(signatures) - sent)
    rows = tuple(withhold(s, policy.withheld, key) for s in live)
    return Batch(**base, signatures=rows, withheld_rows=len(signatures) - len(rows), key_id=fingerprint(key))
