"""The named fleet queries: one SQL text each, run unchanged on DuckDB, Spark and PostgreSQL.

Written in the SQL the three engines share (``NULLS LAST`` spelled out, decimals cast
explicitly, no dialect functions) against three relations: ``signatures`` (one row per
signature, the columns of ``signature.Signature``), ``effects`` (``tenant_id, signature_id,
feature, effect``: one row per changed feature) and, for ``similar``, ``probe`` (``feature,
effect``: the signature looked for). Parameters (``:k``, ``:site``, ...) are validated and
written in as literals by ``render``.

A cross-customer query returns only groups seen at ``:k`` or more distinct customers other than the
caller (``:caller``: a tenant's own rows, crafted or not, never make up the k it is shown), and takes no
value (a minimum, a date) from a group seen at fewer.
"""

from __future__ import annotations

import datetime as dt
import re
from collections.abc import Mapping
from dataclasses import dataclass
from decimal import Decimal

from cellguard.errors import CellguardError, ConfigError, UnknownNameError
from cellguard.fleet.signature import EFFECT_LIMIT

MIN_CUSTOMERS = 5  # default k: a cross-customer result covers at least this many customers


class RefusedAggregate(CellguardError):
    """A cross-customer result over fewer than k customers (from the store or the lake)."""


def first_line(error: object) -> str:
    """An engine's error in one line: its first line that says something, stripped (or its class name)."""
    return next((ln.strip() for ln in str(error).splitlines() if ln.strip()), error.__class__.__name__)


@dataclass(frozen=True)
class NamedQuery:
    name: str
    doc: str
    sql: str
    columns: tuple[tuple[str, str], ...]  # (name, PostgreSQL type) of each result column
    defaults: Mapping[str, object]
    cross_customer: bool = True  # False: rows of single signatures, only within the caller's rights


# the customers behind a group who are not the caller: only they count toward k
_OTHERS = "count(DISTINCT CASE WHEN tenant_id <> :caller THEN tenant_id END)"
# a site is its tenant's: two customers' "s-1" are two sites (a tenant id holds no space)
_SITES = "count(DISTINCT tenant_id || ' ' || site_id) AS sites"

_FREQUENCY = f"""
SELECT cause, robot_model, cellguard_version,
       count(*) AS signatures, {_SITES}, count(DISTINCT tenant_id) AS customers
FROM signatures
GROUP BY cause, robot_model, cellguard_version
HAVING {_OTHERS} >= :k
ORDER BY signatures DESC, cause, robot_model NULLS LAST, cellguard_version NULLS LAST
"""

# k applies to the (cause, policy version) groups before anything is taken from them: "first seen" and
# "deployed" are minimums over groups seen at k or more customers only, so one customer's lone (or old-dated)
# signature neither shows its date nor hides a cause from everyone
_INTRODUCED = f"""
WITH per_version AS (
  SELECT cause, policy_version, min(created_date) AS first_seen, count(*) AS signatures,
         {_SITES}, count(DISTINCT tenant_id) AS customers
  FROM signatures WHERE policy_version IS NOT NULL
  GROUP BY cause, policy_version
  HAVING {_OTHERS} >= :k),
deployed AS (SELECT policy_version, min(first_seen) AS deployed FROM per_version GROUP BY policy_version),
earliest AS (SELECT cause, min(first_seen) AS first_seen FROM per_version GROUP BY cause)
SELECT v.cause, v.policy_version, d.deployed, v.first_seen, v.signatures, v.sites, v.customers
FROM per_version v
JOIN earliest e ON v.cause = e.cause AND v.first_seen = e.first_seen
JOIN deployed d ON v.policy_version = d.policy_version
ORDER BY v.cause, v.policy_version
"""

_FIXES = f"""
SELECT cause, robot_model, recovery, count(*) AS signatures,
       sum(CASE WHEN recovery_outcome = 'success' THEN 1 ELSE 0 END) AS fixed,
       count(DISTINCT tenant_id) AS customers
FROM signatures
GROUP BY cause, robot_model, recovery
HAVING {_OTHERS} >= :k
ORDER BY cause, robot_model NULLS LAST, signatures DESC, recovery NULLS LAST
"""

# an effect that is not a finite number within the clip (NaN, infinite: a store or lake written before
# signatures were checked) is left out, the same on every engine (they order NaN differently, DuckDB fails on it)
_FINITE = f"effect BETWEEN -{EFFECT_LIMIT:.0f} AND {EFFECT_LIMIT:.0f}"

_SIMILAR = f"""
WITH p AS (SELECT feature, sign(effect) * ln(1 + abs(effect)) AS w FROM probe WHERE {_FINITE}),
pn AS (SELECT sqrt(sum(w * w)) AS norm FROM p),
s AS (SELECT signature_id, feature, sign(effect) * ln(1 + abs(effect)) AS w FROM effects WHERE {_FINITE}),
sn AS (SELECT signature_id, sqrt(sum(w * w)) AS norm FROM s GROUP BY signature_id),
d AS (SELECT s.signature_id, sum(s.w * p.w) AS dot FROM s JOIN p ON s.feature = p.feature GROUP BY s.signature_id)
SELECT g.signature_id, g.site_id, g.cause, g.robot_model, g.recovery, g.recovery_outcome,
       CAST(d.dot / (sn.norm * pn.norm) AS DECIMAL(12, 9)) AS similarity
FROM d
JOIN sn ON d.signature_id = sn.signature_id
JOIN signatures g ON g.signature_id = d.signature_id
CROSS JOIN pn
WHERE g.site_id <> :site AND sn.norm > 0 AND pn.norm > 0
ORDER BY CASE WHEN g.robot_model = :robot_model THEN 0 ELSE 1 END, similarity DESC, g.signature_id
LIMIT :limit
"""

QUERIES: dict[str, NamedQuery] = {q.name: q for q in (
    NamedQuery("frequency", "signatures by cause, robot model and cellguard version", _FREQUENCY,
               (("cause", "text"), ("robot_model", "text"), ("cellguard_version", "text"),
                ("signatures", "bigint"), ("sites", "bigint"), ("customers", "bigint")), {"k": MIN_CUSTOMERS}),
    NamedQuery("introduced", "the policy version under which each cause was first seen", _INTRODUCED,
               (("cause", "text"), ("policy_version", "text"), ("deployed", "date"), ("first_seen", "date"),
                ("signatures", "bigint"), ("sites", "bigint"), ("customers", "bigint")), {"k": MIN_CUSTOMERS}),
    NamedQuery("fixes", "the recoveries taken per cause and how often they fixed it", _FIXES,
               (("cause", "text"), ("robot_model", "text"), ("recovery", "text"), ("signatures", "bigint"),
                ("fixed", "bigint"), ("customers", "bigint")), {"k": MIN_CUSTOMERS}),
    NamedQuery("similar", "the signatures nearest to a probe (cosine of log-scaled effect sizes), "
               "same robot model first, other sites only", _SIMILAR,
               (("signature_id", "text"), ("site_id", "text"), ("cause", "text"), ("robot_model", "text"),
                ("recovery", "text"), ("recovery_outcome", "text"), ("similarity", "numeric")),
               {"site": "", "robot_model": "", "limit": 5}, cross_customer=False),
)}

_TEXT = re.compile(r"^[A-Za-z0-9_.:-]{0,64}$")


def named(name: str) -> NamedQuery:
    if name not in QUERIES:
        raise UnknownNameError("fleet query", name, list(QUERIES))
    return QUERIES[name]


def render(query: NamedQuery, params: Mapping[str, object] | None = None, exprs: Mapping[str, str] | None = None,
           relations: Mapping[str, str] | None = None) -> str:
    """The query's SQL with its parameters written in; ``exprs`` replaces parameters with SQL expressions (``k``;
    ``caller``, the tenant whose own rows count toward no k: by default no tenant, every customer counts) and
    ``relations`` what each relation read is (``fleet.signatures``: a name no temporary object can stand for)."""
    values = {**query.defaults, **(params or {})}
    for key in values:
        if key not in query.defaults:
            raise ConfigError(f"query {query.name}: parameter {key!r} unknown; allowed: {', '.join(query.defaults)}")
    exprs = {"caller": literal(""), **(exprs or {})}

    def written(m: re.Match) -> str:
        key = m.group(1)
        return exprs[key] if key in exprs else literal(checked(query, key, values[key]))

    sql = re.sub(r":([a-z_]+)\b", written, query.sql)
    if relations is None:
        return sql
    return re.sub(r"\b(FROM|JOIN)\s+(signatures|effects|probe)\b",
                  lambda m: f"{m.group(1)} {relations[m.group(2)]}", sql)


def checked(query: NamedQuery, key: str, value: object) -> int | str:
    """``value`` if the parameter ``key`` of ``query`` may take it (an integer 1..1000000, or text matching
    ``_TEXT``), else ConfigError naming it: the one rule on every engine and the store."""
    if isinstance(value, bool) or not isinstance(value, (int, str)):
        raise ConfigError(f"query {query.name}: parameter {key} must be an integer or text, got {value!r}")
    if isinstance(value, int) and not 1 <= value <= 1_000_000:
        raise ConfigError(f"query {query.name}: parameter {key} must be 1..1000000, got {value}")
    if isinstance(value, str) and not _TEXT.fullmatch(value):
        raise ConfigError(f"query {query.name}: parameter {key} must match {_TEXT.pattern}, got {value!r}")
    return value


def literal(value: int | str) -> str:
    """A checked value (``checked``, or a tenant id) written as SQL."""
    return str(value) if isinstance(value, int) else f"'{value}'"


def plain(row: Mapping[str, object]) -> dict:
    """A result row with engine types made plain: decimals to float, dates to ISO text."""
    out = {}
    for k, v in row.items():
        if isinstance(v, Decimal):
            v = float(v)
        elif isinstance(v, (dt.date, dt.datetime)):
            v = v.isoformat()[:10]
        out[k] = v
    return out
