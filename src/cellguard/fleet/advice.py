"""What fixed a cause at other sites: the fleet store's ``fixes`` query as advice rows.

Cross-customer, so only as the store allows it: counts over at least k customers, through the
caller's own tenant role. A store that refuses (fewer than k customers) gives no advice; a store
that is down is the caller's to report, the diagnosis goes on without it.
"""

from __future__ import annotations

from cellguard.fleet.queries import MIN_CUSTOMERS, RefusedAggregate


def fleet_fixes(store, k: int = MIN_CUSTOMERS) -> list[dict]:
    """Rows for ``diagnose_record(fleet=...)``: per cause and recovery, signatures tried and fixed,
    counted over at least ``k`` customers (never fewer than the store allows)."""
    try:
        rows = store.run("fixes", {"k": k})
    except RefusedAggregate:
        return []
    return [{"cause": r["cause"], "recovery": r["recovery"], "fixed": int(r["fixed"]), "tried": int(r["signatures"]),
             "customers": int(r["customers"]), "scope": "fleet"} for r in rows if r["recovery"]]
