"""One push from a site: queued batches first, then this one; whatever cannot be sent waits.

Order of work, so that nothing is lost: the batch is built under the policy, written to the
outbox, logged in the audit log, then sent; it leaves the outbox only once the store has taken
it. A store that is down leaves every batch queued for the next push.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from cellguard.fleet.audit import append_audit
from cellguard.fleet.export import Batch, export_batch
from cellguard.fleet.lake import write_signatures
from cellguard.fleet.outbox import Outbox
from cellguard.fleet.policy import DataPolicy
from cellguard.fleet.signature import Signature
from cellguard.fleet.store import StoreUnavailable, TenantStore


@dataclass(frozen=True)
class PushResult:
    batch: Batch
    sent_batches: int  # this one and earlier queued ones
    new_rows: int
    duplicate_rows: int
    queued: int  # batches still in the outbox
    unavailable: str | None = None  # why the store could not be reached

    def to_dict(self) -> dict:
        return {"batch_id": self.batch.batch_id, "export": self.batch.export, "rows": self.batch.rows,
                "withheld_rows": self.batch.withheld_rows, "policy_version": self.batch.policy_version,
                "sent_batches": self.sent_batches, "new_rows": self.new_rows, "duplicate_rows": self.duplicate_rows,
                "queued": self.queued, "unavailable": self.unavailable}


def push(signatures: list[Signature], policy: DataPolicy, site_dir: Path, store: TenantStore | None,
         lake: Path | None = None) -> PushResult:
    """Export ``signatures`` under ``policy`` and send them (and any queued batch) to ``store``."""
    batch = export_batch(signatures, policy)
    outbox = Outbox(site_dir)
    destination = store.where if store is not None else "nowhere"
    if batch.export == "nothing" or batch.rows == 0:
        append_audit(site_dir, batch, "nothing", destination)
    else:
        outbox.put(batch)
        append_audit(site_dir, batch, "queued", destination)
    sent = new = dup = 0
    unavailable = None
    if store is not None:
        try:
            for path, queued in outbox.pending():
                n, d = store.push(queued, retention_days=policy.retention_days)
                if lake is not None and queued.signatures:
                    write_signatures(lake, queued.signatures, queued.batch_id)
                outbox.done(path)
                append_audit(site_dir, queued, "sent" if n else "duplicate", destination)
                sent, new, dup = sent + 1, new + n, dup + d
        except StoreUnavailable as exc:
            unavailable = str(exc)
    return PushResult(batch, sent, new, dup, len(outbox.pending()), unavailable)
