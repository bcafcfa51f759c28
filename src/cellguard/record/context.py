"""The context manifest: what a technician needs months later to read a record correctly.

Policy source and content hash, and for a learned policy the action map in force (resolved: joint,
sign, SI per unit, offset per action, with its own sha256; the model's hash alone reads the same
under a map in rad and one in deg); the embodiment profile's hash and calibration dates (and, for
a profile written by ``identify --write``, its calibration: version id and calibrated MJCF) and
its whole document as ``embodiment show --json`` prints it (the limits the guard enforced, what
was measured; bounded as the profile file is) and, for a scenario's ``calibration``, the file it was
read from, absolute (``replay`` looks for it there, from any working folder); envelope configuration,
fixture datum, site, cell id, scenario and software versions. Short version stamps (``policy``,
``calibration``, ``datum``, ``context``) are hashes of the relevant parts; every index row carries them
so that a query can separate cycles run under different versions. A reader recomputes a record's stamps
from its own context, so an older record (no map, no profile document) keeps the stamps it was written
with.
"""

from __future__ import annotations

import hashlib
import json
import platform
from importlib import metadata

_SOFTWARE = ("cellguard", "mujoco", "numpy", "mcap", "pyarrow", "duckdb", "ruckig")


def build_context(*, scenario, cell, policy, envelope, software: dict | None = None) -> dict:
    """The context of a run, from the objects that make it (all plain JSON values)."""
    profile = cell.profile
    # only a calibrated profile adds the key, so an uncalibrated run's context (and its stamps) reads as before
    calibration = {"calibration": profile.calibration.to_dict()} if profile.calibration is not None else {}
    # a learned policy's action map (MappedPolicy.map_document) is part of the policy: its stamp changes with it
    action_map = getattr(policy, "map_document", None)
    # the calibration file the robot read, resolved when it was read (runtime.build.make_robot)
    file = getattr(cell, "profile_file", None)
    return {
        "site": scenario.site,
        "cell_id": scenario.cell_id,
        "cell": cell.name,
        "policy": {"source": policy.source, "sha256": policy.content_hash(),
                   **({"action_map": action_map} if action_map is not None else {})},
        "embodiment": {"robot": profile.robot, "version": profile.version, "sha256": profile.sha256,
                       "joints": list(profile.joint_names),
                       "calibration_dates": sorted({m.measured for m in profile.measured}), **calibration,
                       "profile": profile.to_dict(), **({"file": str(file)} if file is not None else {})},
        **cell.context(),
        "envelope": envelope.to_dict(),
        "servo_period_ns": cell.dt_ns,
        "scenario": scenario.model_dump(mode="json", exclude={"faults", "process_changes"}),
        "software": software or software_versions(),
    }


def software_versions() -> dict:
    out = {"python": platform.python_version()}
    for name in _SOFTWARE:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out


def versions(context: dict) -> dict[str, str]:
    """Short stamps of the parts that change how a cycle reads: policy (its action map included), calibration
    (the embodiment), datum, whole. The profile's document and file are left out of the calibration stamp: its
    sha256 is in it, and the same profile keeps the stamp records made before they were recorded have (and read
    from another folder, the same stamp)."""
    calibration = {k: context.get(k) for k in ("embodiment", "camera_calibration", "tool_offset")}
    if isinstance(calibration["embodiment"], dict):
        calibration["embodiment"] = {k: v for k, v in calibration["embodiment"].items()
                                    if k not in ("profile", "file")}
    return {
        "policy_version": _digest(context.get("policy")),
        "calibration_version": _digest(calibration),
        "datum_version": _digest(context.get("fixture_datum")),
        "context_version": _digest(context),
    }


def changed_keys(before: dict | None, after: dict) -> list[str]:
    """Top-level keys whose value differs (all of them for the first context)."""
    if before is None:
        return sorted(after)
    return sorted(k for k in before.keys() | after.keys() if before.get(k) != after.get(k))


def _digest(value) -> str:
    return hashlib.sha256(json.dumps(value, sort_keys=True, default=str).encode()).hexdigest()[:12]
