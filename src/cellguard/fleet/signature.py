"""A fault signature: what one diagnosed finding may say about a fault once it leaves the site.

One row per finding: the cause, the robot model and cell type, the changed features as
standardised effect sizes (change over the baseline's scale, dimensionless; never a raw value),
onset and detection delay in cycles, the policy and calibration version stamps, the cellguard
version, and the recovery taken with its outcome when known. No ticks, no images, no names:
a tenant id and a site id, both opaque, assigned by the fleet operator.

The signature id is the content hash of every field, so a retried upload is the same row.
"""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields, replace

from cellguard.errors import ConfigError
from cellguard.record.context import versions

SCHEMA_VERSION = 1
ID_PATTERN = r"^[a-z0-9][a-z0-9_-]{0,39}$"  # tenant and site ids: opaque, lower-case, short; use re.fullmatch
# (re.match lets "$" match before a final newline: "t-acme\n" would pass)
EFFECT_LIMIT = 1e6  # [baseline scales] larger effect sizes are clipped (a feature with no spread)


class SignatureError(ConfigError):
    """A signature that cannot be read: a newer schema version, a missing or mistyped field."""


@dataclass(frozen=True)
class Signature:
    """One finding of one run, as it may leave the site (before the data policy withholds fields)."""

    tenant_id: str
    site_id: str
    created_date: str  # ISO date of the run's start (UTC); partitions the lake
    cause: str
    confidence: float | None = None
    robot_model: str | None = None
    cell_type: str | None = None
    effects: Mapping[str, float] | None = field(default=None)  # feature -> effect size [baseline scales]
    onset_cycle: int | None = None
    detection_delay_cycles: int | None = None  # cycles from onset to the first drift alarm
    policy_version: str | None = None
    calibration_version: str | None = None
    cellguard_version: str | None = None
    recovery: str | None = None  # the behaviour that got the cell running again most often in this finding
    recovery_outcome: str | None = None  # "success" if it fixed at least one cycle, else "failed"
    schema_version: int = SCHEMA_VERSION

    @property
    def signature_id(self) -> str:
        """sha256 of the canonical JSON of every field, 32 hex digits."""
        body = json.dumps(self._fields(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(body.encode()).hexdigest()[:32]

    def to_dict(self) -> dict:
        return {"signature_id": self.signature_id, **self._fields()}

    def _fields(self) -> dict:
        out = asdict(self)
        out["effects"] = dict(sorted(self.effects.items())) if self.effects is not None else None
        return out


WITHHOLDABLE = tuple(f.name for f in fields(Signature)
                     if f.name not in ("tenant_id", "site_id", "created_date", "cause", "schema_version"))


def withhold(sig: Signature, names: tuple[str, ...]) -> Signature:
    """The signature with the named fields emptied (a new id: the withheld fields are not in it)."""
    return replace(sig, **{n: None for n in names})


def from_dict(raw: object) -> Signature:
    """A signature from its JSON; a newer schema version or an unknown field is refused in one line."""
    if not isinstance(raw, Mapping):
        raise SignatureError(f"signature: expected a mapping, got {type(raw).__name__}")
    version = raw.get("schema_version")
    if not isinstance(version, int) or version < 1:
        raise SignatureError(f"signature.schema_version: expected an integer 1..{SCHEMA_VERSION}, got {version!r}")
    if version > SCHEMA_VERSION:
        raise SignatureError(f"signature.schema_version: {version} is newer than this cellguard reads "
                             f"(1..{SCHEMA_VERSION}); upgrade cellguard")
    names = {f.name for f in fields(Signature)}
    body = {k: v for k, v in raw.items() if k != "signature_id"}
    for key in body:
        if key not in names:
            raise SignatureError(f"signature.{key}: unknown field; allowed: {', '.join(sorted(names))}")
    for key in ("tenant_id", "site_id", "created_date", "cause"):
        if not isinstance(body.get(key), str):
            raise SignatureError(f"signature.{key}: required text, got {body.get(key)!r}")
    try:
        dt.date.fromisoformat(body["created_date"])
    except ValueError:
        raise SignatureError(f"signature.created_date: expected an ISO date (YYYY-MM-DD), "
                             f"got {body['created_date']!r}") from None
    sig = Signature(**body)
    if "signature_id" in raw and raw["signature_id"] != sig.signature_id:
        raise SignatureError(f"signature.signature_id: {raw['signature_id']!r} does not match its content")
    return sig


def signatures_of(diagnosis: Mapping, context: Mapping, tenant_id: str, site_id: str,
                  start_date: dt.date) -> list[Signature]:
    """One signature per finding of ``diagnosis`` (its ``to_dict()``), in the record's ``context``."""
    stamps = versions(dict(context))
    software = context.get("software") or {}
    changes = {c["signal"]: c for c in diagnosis.get("changes", [])}
    out = []
    for f in diagnosis.get("findings", []):
        tried = sorted((r for r in diagnosis.get("fixes", []) if (r["cause"], r["cycle"]) == (f["cause"], f["cycle"])),
                       key=lambda r: (-r["fixed"], -r["tried"], r["recovery"]))
        mine = [changes[s] for s in f.get("signals", []) if s in changes]
        effects = {c["signal"]: _effect(c["scales"]) for c in mine if _finite(c["scales"])}
        onset = min((c["onset"] for c in mine), default=f["cycle"])
        alarm = min((c["alarm_cycle"] for c in mine), default=f["cycle"])
        out.append(Signature(
            tenant_id=tenant_id, site_id=site_id, created_date=start_date.isoformat(), cause=f["cause"],
            confidence=float(f["confidence"]), robot_model=(context.get("embodiment") or {}).get("robot"),
            cell_type=context.get("cell"), effects=effects, onset_cycle=int(onset),
            detection_delay_cycles=max(0, int(alarm) - int(onset)),
            policy_version=stamps["policy_version"], calibration_version=stamps["calibration_version"],
            cellguard_version=software.get("cellguard"),
            recovery=tried[0]["recovery"] if tried else None,
            recovery_outcome=("success" if tried[0]["fixed"] else "failed") if tried else None))
    return out


def _finite(x) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x)


def _effect(x: float) -> float:
    return round(max(-EFFECT_LIMIT, min(EFFECT_LIMIT, float(x))), 4)
