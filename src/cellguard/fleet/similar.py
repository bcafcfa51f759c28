"""Similar faults: the signatures nearest to a fault, from other sites, with what fixed them.

Nearest by the named ``similar`` query (cosine of log-scaled effect sizes, same robot model
first), run as the caller's tenant role, so the store's row-level security decides what it may
see. What fixed each neighbour's cause, and how often, comes from the cross-customer ``fixes``
query when at least k customers back it, else from the caller's own signatures.

A run's findings leave the site as probes (their effect sizes, feature names, robot model and site
id reach the store): only under a policy that exports signatures, and each command's probes are
logged in the site's audit log (status ``probed``) before they are sent, as an export is.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from cellguard.errors import ConfigError
from cellguard.fleet.audit import append_audit
from cellguard.fleet.export import Batch
from cellguard.fleet.policy import DataPolicy
from cellguard.fleet.signature import Signature
from cellguard.fleet.store import RefusedAggregate, TenantStore


@dataclass(frozen=True)
class Neighbour:
    signature_id: str
    site_id: str
    cause: str
    robot_model: str | None
    similarity: float
    fixes: tuple[dict, ...]  # {recovery, signatures, fixed, scope}

    def to_dict(self) -> dict:
        return {**{k: getattr(self, k) for k in ("signature_id", "site_id", "cause", "robot_model", "similarity")},
                "fixes": list(self.fixes)}


def probe_of(store: TenantStore, signature_id: str) -> Signature:
    """The caller's own signature by id (another tenant's id reads as not found)."""
    with store.connection() as con:
        row = con.execute("SELECT tenant_id, site_id, created_date, cause, robot_model FROM fleet.signatures "
                          "WHERE signature_id = %s", (signature_id,)).fetchone()
        if row is None:
            raise ConfigError(f"SIGNATURE_ID {signature_id!r}: no such signature among yours")
        effects = dict(con.execute("SELECT feature, effect FROM fleet.effects WHERE signature_id = %s",
                                   (signature_id,)).fetchall())
    tenant, site, day, cause, model = row
    return Signature(tenant, site, day.isoformat(), cause, robot_model=model, effects=effects)


def as_sent(probe: Signature, withheld: tuple[str, ...]) -> Signature:
    """``probe`` as the site's data policy lets it leave for the store: a withheld robot model is not sent (it only
    ranks the same model first); withheld effects leave nothing to compare, and a query would send them."""
    if "effects" in withheld:
        raise ConfigError("--policy: it withholds effects, which `fleet similar` sends to the store as its probe; "
                          "nothing sent")
    return replace(probe, robot_model=None) if "robot_model" in withheld else probe


def check_policy(policy: DataPolicy) -> None:
    """ConfigError unless ``policy`` lets findings leave the site as signatures: a probe sends what
    ``aggregates_only`` and ``nothing`` keep at the site. Checked before the runs are diagnosed."""
    if policy.export != "signatures":
        raise ConfigError(f"--policy: export: {policy.export}; `fleet similar` sends each finding's effect sizes, "
                          f"robot model and site to the store, which only export: signatures allows; nothing sent")


def log_probes(site_dir: Path, probes: list[Signature], policy: DataPolicy, destination: str) -> None:
    """Append the probes ``similar`` will send (those with effect sizes, ``as_sent``'s) to the site's audit log
    as one export, status ``probed``: the log names everything that left the site."""
    rows = tuple({"tenant_id": p.tenant_id, "site_id": p.site_id, "robot_model": p.robot_model,
                  "effects": p.effects} for p in probes if p.effects)
    if rows:
        append_audit(site_dir, Batch(policy.tenant, policy.site, policy.version, policy.export, rows), "probed",
                     destination)


def similar(store: TenantStore, probe: Signature, limit: int = 5) -> list[Neighbour]:
    """The ``limit`` nearest signatures to ``probe`` from sites other than its own."""
    if not probe.effects:
        return []
    rows = store.run("similar", {"site": probe.site_id, "robot_model": probe.robot_model or "", "limit": limit},
                     probe=sorted(probe.effects.items()), scope="own")
    fixes = _fixes(store)
    return [Neighbour(r["signature_id"], r["site_id"], r["cause"], r["robot_model"], r["similarity"],
                      tuple(f for f in fixes if f["cause"] == r["cause"] and f["robot_model"] == r["robot_model"]))
            for r in rows]


def _fixes(store: TenantStore) -> list[dict]:
    try:
        rows, scope = store.run("fixes"), "fleet"
    except RefusedAggregate:
        rows, scope = store.run("fixes", scope="own"), "own"
    return [{"cause": r["cause"], "robot_model": r["robot_model"], "recovery": r["recovery"],
             "signatures": r["signatures"], "fixed": r["fixed"], "scope": scope} for r in rows]
