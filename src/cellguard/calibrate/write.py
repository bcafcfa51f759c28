"""Write identified parameters back into an embodiment profile: versioned, the old version kept, atomic.

Per joint, ``friction``, ``damping`` and ``armature`` replace the profile's ``measured`` entries of
the same joint and parameter (value, unit, date, method naming the records and the 95 % interval).
The profile's ``version`` becomes ``DATE-cal-HASH`` (the calibration version). The previous file is
kept beside it as ``NAME.OLD_VERSION.yaml``; the new one is checked against the model before it
replaces the old (written beside and renamed), so a failure leaves the profile as it was.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import yaml

from cellguard.calibrate.identify import CalibrationError
from cellguard.embodiment.profile import parse_profile
from cellguard.errors import OutputError, ProfileError
from cellguard.output import write_output
from cellguard.yaml_file import parse_yaml, read_bounded

WRITTEN = ("friction", "damping", "armature")  # per-joint parameters the profile's units express


def write_profile(path: Path, cell, result: dict, date: str) -> str:
    """Update ``path`` (``cell``'s profile) with ``result`` (from ``identify``); return the new version."""
    path = Path(path)
    old_bytes = read_bounded(path, "profile", ProfileError)
    raw = parse_yaml(old_bytes, str(path), ProfileError)
    if not isinstance(raw, dict) or raw.get("robot") != cell.name:
        robot = raw.get("robot") if isinstance(raw, dict) else None
        raise CalibrationError(f"--write: {path} is a profile of robot {robot!r}; the records are of {cell.name!r}")
    new = [e for e in result["estimates"] if e["parameter"] in WRITTEN and e["interval"] is not None]
    if not new:
        raise CalibrationError(f"--write: nothing identified to write (of {', '.join(WRITTEN)})")
    method = f"sysid: {', '.join(result['records'])} (regression on mj_inverse)"
    replaced = {(e["joint"], e["parameter"]) for e in new}
    measured = [m for m in raw.get("measured") or [] if (m.get("joint"), m.get("parameter")) not in replaced]
    for e in new:
        lo, hi = e["interval"]
        measured.append({"joint": e["joint"], "parameter": e["parameter"], "value": f"{e['value']:.6g} {e['unit']}",
                         "measured": date, "method": f"{method}; 95 % interval [{lo:.6g}, {hi:.6g}] {e['unit']}"})
    old_version = str(raw.get("version", "unversioned"))
    raw["measured"] = measured
    digest = hashlib.sha256(json.dumps(measured, sort_keys=True).encode()).hexdigest()[:8]
    raw["version"] = f"{date}-cal-{digest}"
    text = yaml.safe_dump(raw, sort_keys=False, allow_unicode=True)
    parse_profile(cell.model, text.encode(), str(path))  # the new profile loads before it replaces the old
    kept = path.with_name(f"{path.stem}.{old_version}{path.suffix}")
    keep = not kept.is_file()  # a folder there is no kept profile: writing it fails, before anything is changed
    if keep:
        write_output(kept, old_bytes, "previous profile")
    try:
        write_output(path, text, "profile")
    except OutputError:
        if keep:  # the command failed: leave the folder as it was
            kept.unlink(missing_ok=True)
        raise
    return raw["version"]
