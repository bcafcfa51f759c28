"""What a caller may read from the Parquet lake: its own rows, or aggregates over at least k customers.

The store's rules (``store.py``), kept on the lake: a tenant's row-level query (``similar``, or
any query in scope "own") reads its own folder only and never opens another tenant's file; a
cross-customer query is refused while fewer than k customers have signatures in the lake and
returns only the groups seen at k or more, k = max(the one asked for, the lake's least,
default 5). It reads every tenant's folder, so it runs where those are readable: the operator's
side (a tenant who holds only its own folder's rights gets the aggregate, not the files). The
operator (``tenant`` None) reads every row at any k: the benchmarks and engine tests run as it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from cellguard.errors import ConfigError
from cellguard.fleet.lake import files, paths, tenant_dir, tenants
from cellguard.fleet.queries import MIN_CUSTOMERS, NamedQuery, RefusedAggregate

RELATIONS = ("signatures", "effects")
SCOPES = ("fleet", "own")


@dataclass(frozen=True)
class Access:
    """The files one query may read and the parameters it runs with."""

    globs: Mapping[str, str]  # relation -> glob of its files
    params: Mapping[str, object]
    tenant: str | None = None  # whose folder only; None: every tenant's

    def paths(self, lake: Path, relation: str) -> list[str]:
        """The files of ``relation`` listed (the lake's path taken literally, not as a pattern)."""
        return paths(lake, relation, self.tenant)


def access(lake: Path, query: NamedQuery, params: Mapping | None, tenant: str | None, scope: str = "fleet",
           min_customers: int = MIN_CUSTOMERS) -> Access:
    """What ``tenant`` (None: the operator) may read for ``query`` in ``scope``, or RefusedAggregate."""
    if scope not in SCOPES:
        raise ConfigError(f"--scope: {scope!r}; allowed: {', '.join(SCOPES)}")
    if tenant is not None:
        tenant_dir(lake, tenant)  # an id, never a glob or a path
    params = dict(params or {})
    every = {r: files(lake, r) for r in RELATIONS}
    if tenant is None:
        return Access(every, params)
    if scope == "fleet" and query.cross_customer:
        asked = params.get("k", query.defaults.get("k", MIN_CUSTOMERS))
        k = max(asked, min_customers) if isinstance(asked, int) and not isinstance(asked, bool) else asked
        n = len(tenants(lake))
        if isinstance(k, int) and n < k:
            raise RefusedAggregate(f"cross-customer query {query.name} refused: signatures from fewer than {k} "
                                   f"customers")  # not how many: a count under k is not for the caller
        return Access(every, {**params, "k": k})
    if tenant not in tenants(lake):
        raise ConfigError(f"--tenant {tenant}: no signatures of this tenant in {lake}")
    own = {r: files(lake, r, tenant) for r in RELATIONS}
    return Access(own, {**params, "k": 1} if "k" in query.defaults else params, tenant)
