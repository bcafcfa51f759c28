"""Enforcing a data policy at export: from a site's signatures to the batch that may leave it.

``signatures``: each signature with the withheld fields emptied; ``aggregates_only``: counts per
(cause, robot model, cell type), a count over fewer than ``min_group_size`` signatures not sent;
``nothing``: an empty batch. Signatures past the retention period are never sent. The batch is
all that leaves the site: it holds no record, no tick and no raw feature value.
"""

from __future__ import annotations

import datetime as dt
import hashlib
import json
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass

from cellguard.fleet.policy import DataPolicy, PolicyError
from cellguard.fleet.signature import Signature, from_dict, withhold


@dataclass(frozen=True)
class Batch:
    """What one push sends: rows under one policy version; ``batch_id`` is its content hash."""

    tenant_id: str
    site_id: str
    policy_version: str
    export: str
    signatures: tuple[dict, ...] = ()
    aggregates: tuple[dict, ...] = ()
    withheld_rows: int = 0  # signatures kept at the site by the policy (too few, too old, or nothing)

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
               "withheld_rows": self.withheld_rows}
        return {"batch_id": self.batch_id, **out} if with_id else out

    @classmethod
    def from_dict(cls, raw: dict) -> Batch:
        """A batch from its JSON; each signature is read as one (a newer schema version, an unknown
        field or a forged id raises SignatureError)."""
        return cls(raw["tenant_id"], raw["site_id"], raw["policy_version"], raw["export"],
                   tuple(from_dict(s).to_dict() for s in raw["signatures"]), tuple(raw["aggregates"]),
                   raw.get("withheld_rows", 0))


def export_batch(signatures: Sequence[Signature], policy: DataPolicy, today: dt.date | None = None) -> Batch:
    """The batch ``policy`` lets leave the site, from the site's ``signatures``."""
    today = today or dt.datetime.now(dt.timezone.utc).date()
    oldest = today - dt.timedelta(days=policy.retention_days)
    live = [s for s in signatures if dt.date.fromisoformat(s.created_date) >= oldest]
    base = dict(tenant_id=policy.tenant, site_id=policy.site, policy_version=policy.version, export=policy.export)
    if policy.export == "nothing":
        return Batch(**base, withheld_rows=len(signatures))
    if policy.export == "aggregates_only":
        counts = Counter((s.cause, s.robot_model, s.cell_type, s.created_date[:7]) for s in live)
        rows = tuple({"cause": c, "robot_model": m, "cell_type": t, "month": mo, "signatures": n}
                     for (c, m, t, mo), n in sorted(counts.items(), key=str) if n >= policy.min_group_size)
        sent = sum(r["signatures"] for r in rows)
        return Batch(**base, aggregates=rows, withheld_rows=len(signatures) - sent)
    for s in live:  # a signature from another tenant or site is not this site's to send
        if (s.tenant_id, s.site_id) != (policy.tenant, policy.site):
            raise PolicyError(f"signature.tenant_id/site_id: {s.tenant_id}/{s.site_id} is not the policy's "
                              f"{policy.tenant}/{policy.site}")
    rows = tuple(withhold(s, policy.withheld).to_dict() for s in live)
    return Batch(**base, signatures=rows, withheld_rows=len(signatures) - len(rows))
