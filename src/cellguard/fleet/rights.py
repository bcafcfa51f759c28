"""What a caller may read from the Parquet lake: its own rows, or aggregates over at least k customers.

The store's rules (``store.py``), kept on the lake: a tenant's row-level query (``similar``, or
any query in scope "own") reads its own folder only and never opens another tenant's file; a
cross-customer query is refused while fewer than k customers other than the caller have
signatures in the lake and returns only the groups seen at k or more of them (the caller's own
rows, crafted or not, count toward no k), k = max(the one asked for, the lake's least, default
5). It reads every tenant's folder, so it runs where those are readable: the operator's side (a
tenant who holds only its own folder's rights gets the aggregate, not the files). The operator
(``tenant`` None) reads every row at any k: the benchmarks and engine tests run as it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from cellguard.errors import ConfigError
from cellguard.fleet.lake import paths, tenant_dir, tenants
from cellguard.fleet.queries import MIN_CUSTOMERS, NamedQuery, RefusedAggregate, checked, literal

SCOPES = ("fleet", "own")


@dataclass(frozen=True)
class Access:
    """The files one query may read and the parameters it runs with."""

    params: Mapping[str, object]
    tenant: str | None = None  # whose folder only; None: every tenant's
    caller: str | None = None  # a cross-customer query's caller, whose own rows count toward no k

    def paths(self, lake: Path, relation: str) -> list[str]:
        """The files of ``relation`` listed (the lake's path taken literally, not as a pattern)."""
        return paths(lake, relation, self.tenant)

    @property
    def exprs(self) -> dict[str, str]:
        """What ``queries.render`` writes for ``:caller``: this caller (none: every customer counts)."""
        return {"caller": literal(self.caller)} if self.caller is not None else {}


def access(lake: Path, query: NamedQuery, params: Mapping | None, tenant: str | None, scope: str = "fleet",
           min_customers: int = MIN_CUSTOMERS) -> Access:
    """What ``tenant`` (None: the operator) may read for ``query`` in ``scope``, or RefusedAggregate."""
    if scope not in SCOPES:
        raise ConfigError(f"--scope: {scope!r}; allowed: {', '.join(SCOPES)}")
    if tenant is not None:
        tenant_dir(lake, tenant)  # an id, never a glob or a path
    params = dict(params or {})
    if tenant is None:
        return Access(params)
    if scope == "fleet" and query.cross_customer:
        k = max(checked(query, "k", params.get("k", query.defaults.get("k", MIN_CUSTOMERS))), min_customers)
        if len(set(tenants(lake)) - {tenant}) < k:  # the caller's own folder is not one of the k
            raise RefusedAggregate(f"cross-customer query {query.name} refused: signatures from fewer than {k} "
                                   f"customers")  # not how many: a count under k is not for the caller
        return Access({**params, "k": k}, caller=tenant)
    if tenant not in tenants(lake):
        raise ConfigError(f"--tenant {tenant}: no signatures of this tenant in {lake}")
    return Access({**params, "k": 1} if "k" in query.defaults else params, tenant)
