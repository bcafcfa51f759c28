"""A customer's data policy: what may leave a site, which fields are withheld, how long rows live.

```yaml
tenant: t-acme01             # opaque ids the fleet operator assigned
site: s-0042
export: signatures           # required: signatures | aggregates_only | nothing
min_group_size: 5            # aggregates_only: a count over fewer signatures is not sent
withheld: [policy_version]   # signature fields never sent (see signature.WITHHOLDABLE)
retention_days: 365          # rows older than this are not sent and are deleted from the store
```

Validated at load (an unknown key, a missing ``tenant``, ``site`` or ``export``, a wrong type or an impossible
value raises PolicyError naming the key) and enforced at export (``export.py``). ``export`` has no default in a
file: a policy that left it out exported every signature, a customer's silence taken as consent to the most that
leaves. The policy version is the hash of its content.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import asdict, dataclass
from pathlib import Path

from cellguard.errors import ConfigError
from cellguard.fleet.signature import ID_PATTERN, WITHHOLDABLE
from cellguard.yaml_file import read_yaml, reject_unknown_keys

EXPORTS = ("signatures", "aggregates_only", "nothing")
KEYS = ("tenant", "site", "export", "min_group_size", "withheld", "retention_days")


class PolicyError(ConfigError):
    """A data policy file that cannot be enforced."""


@dataclass(frozen=True)
class DataPolicy:
    tenant: str
    site: str
    export: str = "signatures"
    min_group_size: int = 5
    withheld: tuple[str, ...] = ()
    retention_days: int = 365

    def __post_init__(self):
        for key in ("tenant", "site"):
            value = getattr(self, key)
            if not isinstance(value, str) or not re.fullmatch(ID_PATTERN, value):
                raise PolicyError(f"policy.{key}: expected an opaque id matching {ID_PATTERN}, got {value!r}")
        if self.export not in EXPORTS:
            raise PolicyError(f"policy.export: {self.export!r}; allowed: {', '.join(EXPORTS)}")
        _int(self.min_group_size, "min_group_size", 2, 1_000_000)
        _int(self.retention_days, "retention_days", 1, 36_500)
        if not isinstance(self.withheld, tuple) or not all(isinstance(w, str) for w in self.withheld):
            raise PolicyError(f"policy.withheld: expected a list of field names, got {self.withheld!r}")
        for name in self.withheld:
            if name not in WITHHOLDABLE:
                raise PolicyError(f"policy.withheld: {name!r} cannot be withheld; allowed: {', '.join(WITHHOLDABLE)}")

    @property
    def version(self) -> str:
        """12 hex digits of the policy's canonical JSON: the audit log names the policy by it."""
        return hashlib.sha256(json.dumps(asdict(self), sort_keys=True).encode()).hexdigest()[:12]


def parse_policy(raw: object, origin: str = "policy", sends: bool = True) -> DataPolicy:
    """The policy ``raw`` states; ``sends`` False for a command that sends nothing (``fleet withdraw``), which
    takes a file written before ``export`` was required, so a site can take back what it pooled under it."""
    if not isinstance(raw, dict):
        raise PolicyError(f"{origin}: expected a mapping of keys, got {type(raw).__name__}")
    reject_unknown_keys(raw, KEYS, f"{origin}: ", PolicyError)
    for key in ("tenant", "site"):
        if key not in raw:
            raise PolicyError(f"{origin}: {key}: required")
    if sends and "export" not in raw:
        raise PolicyError(f"{origin}: export: required, what may leave the site: {' | '.join(EXPORTS)}")
    withheld = raw.get("withheld", [])
    if not isinstance(withheld, list):
        raise PolicyError(f"{origin}: withheld: expected a list of field names, got {withheld!r}")
    try:
        return DataPolicy(**{**raw, "withheld": tuple(withheld)})
    except PolicyError as exc:
        raise PolicyError(f"{origin}: {exc}") from None


def load_policy(path: Path, sends: bool = True) -> DataPolicy:
    return parse_policy(read_yaml(path, "data policy", PolicyError), origin=str(path), sends=sends)


def _int(value, key: str, lo: int, hi: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise PolicyError(f"policy.{key}: expected an integer {lo}..{hi}, got {value!r}")
