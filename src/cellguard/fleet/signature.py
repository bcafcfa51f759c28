"""A fault signature: what one diagnosed finding may say about a fault once it leaves the site.

One row per finding: the cause, the robot model and cell type, the changed features as
standardised effect sizes (change over the baseline's scale, dimensionless; never a raw value),
onset and detection delay in cycles, the policy and calibration version stamps, the cellguard
version, and the recovery taken with its outcome when known. No ticks, no images, no names:
a tenant id and a site id, both opaque, assigned by the fleet operator.

The signature id is an HMAC-SHA256, under the site's own secret key (``site_key.py``: it never
leaves the site), of every field as diagnosed, before the data policy withholds any: a retried
upload from the same site is the same row, and a push under a policy that withholds more replaces
the row it sent before (the store and the lake keep one row per id, the latest). Keyed, because an
unkeyed hash of withheld fields can be inverted by trying the values other rows show openly.

Every field is checked when a signature is made or read (a queued batch): its type, a finite
number in range, text without control characters, so nothing malformed reaches the store or the
lake (PostgreSQL would coerce "1e3" and take a NaN; the lake cannot write either).
"""

from __future__ import annotations

import datetime as dt
import hashlib
import hmac
import json
import math
import re
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields

from cellguard.errors import ConfigError
from cellguard.record.context import versions

SCHEMA_VERSION = 1
ID_PATTERN = r"^[a-z0-9][a-z0-9_-]{0,39}$"  # tenant and site ids: opaque, lower-case, short; use re.fullmatch
# (re.match lets "$" match before a final newline: "t-acme\n" would pass)
EFFECT_LIMIT = 1e6  # [baseline scales] larger effect sizes are clipped (a feature with no spread)
OUTCOMES = ("success", "failed")
_TEXT_FIELDS = ("cause", "robot_model", "cell_type", "policy_version", "calibration_version", "cellguard_version",
                "recovery")
_ID = re.compile(r"[0-9a-f]{32}")


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

    def __post_init__(self):
        for key in ("tenant_id", "site_id"):
            if not isinstance(getattr(self, key), str) or not re.fullmatch(ID_PATTERN, getattr(self, key)):
                raise SignatureError(f"signature.{key}: expected an opaque id matching {ID_PATTERN}, "
                                     f"got {getattr(self, key)!r}")
        _date(self.created_date)
        for key in _TEXT_FIELDS:
            check_text(getattr(self, key), f"signature.{key}", required=key == "cause")
        if self.recovery_outcome not in (None, *OUTCOMES):
            raise SignatureError(f"signature.recovery_outcome: {self.recovery_outcome!r}; allowed: "
                                 f"{', '.join(OUTCOMES)} or null")
        _number(self.confidence, "signature.confidence", 0.0, 1.0)
        for key in ("onset_cycle", "detection_delay_cycles"):
            value = getattr(self, key)
            if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 0):
                raise SignatureError(f"signature.{key}: expected a cycle count (an integer >= 0) or null, "
                                     f"got {value!r}")
        if self.effects is not None:
            if not isinstance(self.effects, Mapping):
                raise SignatureError(f"signature.effects: expected a mapping of feature to effect size, "
                                     f"got {type(self.effects).__name__}")
            for feature, value in self.effects.items():
                check_text(feature, "signature.effects (a feature name)", required=True)
                _number(value, f"signature.effects.{feature}", -EFFECT_LIMIT, EFFECT_LIMIT)

    def signature_id(self, key: bytes) -> str:
        """HMAC-SHA256 under the site's ``key`` of the canonical JSON of every field as diagnosed, 32 hex
        digits: the same finding keeps its id at its site, and no one without the key can test a guess
        of a withheld field against it."""
        body = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))
        return hmac.new(key, body.encode(), hashlib.sha256).hexdigest()[:32]

    def to_dict(self) -> dict:
        """Every field as diagnosed (no id: that needs the site's key, see ``withhold``)."""
        out = asdict(self)
        out["effects"] = dict(sorted(self.effects.items())) if self.effects is not None else None
        return out


WITHHOLDABLE = tuple(f.name for f in fields(Signature)
                     if f.name not in ("tenant_id", "site_id", "created_date", "cause", "schema_version"))


def withhold(sig: Signature, names: tuple[str, ...], key: bytes) -> dict:
    """The row that leaves the site: the signature's fields with the named ones emptied, under the id of
    the signature as diagnosed, keyed with the site's ``key`` (the same finding keeps its id whatever a
    policy withholds, and the id tells nothing of what was withheld)."""
    return {"signature_id": sig.signature_id(key), **sig.to_dict(), **{n: None for n in names}}


def row_from_dict(raw: object) -> dict:
    """A sent row (``withhold``'s) from its JSON, every field checked; its id is required and kept (it is
    keyed with the site's secret over fields the row may no longer hold, so it cannot be checked here)."""
    row = from_dict(raw).to_dict()
    given = raw.get("signature_id")
    if not isinstance(given, str) or not _ID.fullmatch(given):
        raise SignatureError(f"signature.signature_id: expected 32 hex digits, got {given!r}")
    return {"signature_id": given, **row}


def from_dict(raw: object) -> Signature:
    """A signature from its JSON (its id, if any, is not read: see ``row_from_dict``); a newer schema
    version, an unknown, missing or mistyped field is refused in one line naming it."""
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
        if key not in body:
            raise SignatureError(f"signature.{key}: required")
    return Signature(**body)


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


def _date(value: object) -> None:
    """An ISO date, YYYY-MM-DD only (``date.fromisoformat`` also takes 20261120 and week dates)."""
    try:
        dt.date.fromisoformat(value if re.fullmatch(r"[0-9]{4}-[0-9]{2}-[0-9]{2}", value) else "")
    except (TypeError, ValueError):
        raise SignatureError(f"signature.created_date: expected an ISO date (YYYY-MM-DD), got {value!r}") from None


def check_text(value: object, name: str, required: bool = False) -> None:
    """Printable text (it reaches an operator's terminal and the store's queries), at most 200 characters;
    null too unless ``required``."""
    if value is None and not required:
        return
    if not isinstance(value, str) or not value.isprintable() or len(value) > 200 or (required and not value):
        shown = repr(value) if len(repr(value)) <= 80 else f"{repr(value)[:60]}... ({len(repr(value))} characters)"
        raise SignatureError(f"{name}: expected {'' if required else 'null or '}printable text of at most 200 "
                             f"characters, got {shown}")


def _number(value: object, name: str, lo: float, hi: float) -> None:
    """A finite number in [lo, hi] or null; a quoted number ("0.5") or true is not one."""
    if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))
                              or not math.isfinite(value) or not lo <= value <= hi):
        raise SignatureError(f"{name}: expected a finite number {lo:g}..{hi:g} or null, got {value!r}")


def _finite(x) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x)


def _effect(x: float) -> float:
    return round(max(-EFFECT_LIMIT, min(EFFECT_LIMIT, float(x))), 4)
