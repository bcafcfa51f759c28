"""Write identified parameters back into an embodiment profile: versioned, old versions kept, atomic.

Per joint, ``friction``, ``damping`` and ``armature`` replace the profile's ``measured`` entries of
the same joint and parameter (value, unit, date, method naming the records and the interval). The
calibration gets a version id ``DATE-cal-HASH`` (a hash of the whole profile it writes, the calibrated MJCF
and the version it replaces, so a second calibration is always a new version, and two profiles that differ never
share one: a write whose id's MJCF or kept copy exists with other contents is refused, and so is a profile edited
by hand that kept the version of a copy kept beside it). Beside the profile:

    NAME.VERSION.xml      the calibrated MJCF (the commissioned model with the profile's measured joint
                          terms and the identified payload); the profile's ``model`` names it
    NAME.OLD_VERSION.yaml the profile as it was before (kept, never overwritten)

The profile's ``calibration`` block (version, MJCF, date, records, previous version) is what a run
with ``calibration: PROFILE`` carries into every record's context. Every file is written beside its
target and renamed; the new profile is checked against the calibrated model first, and a failure
removes what this write had added, so the folder is left as it was. Concurrent writes take turns (a lock
on the folder): the second reads the first's profile and names its version as ``previous``. A profile named
through a symbolic link is written where the link points (the link is kept), with its MJCF and kept copy
beside it.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
from dataclasses import dataclass
from pathlib import Path

import mujoco

from cellguard.calibrate.identify import CalibrationError, describe_value, negative_values, refuse_ahead
from cellguard.calibrate.mjcf import calibrated_mjcf
from cellguard.calibrate.torque_model import JointTerms
from cellguard.embodiment.profile import kept_copy, parse_profile
from cellguard.errors import OutputError, ProfileError
from cellguard.output import NAME_MAX, folder_locked, write_output
from cellguard.yaml_file import dump_yaml, parse_yaml, read_bounded

WRITTEN = ("friction", "damping", "armature")  # per-joint parameters the profile's units express
IDENTIFIED = "sysid: "  # how a measured value's method starts where identify --write wrote it
NEW_VERSION = "YYYY-MM-DD-cal-HASHHASH"  # the form of the version a write makes (``DATE-cal-HASH``): its length


@dataclass(frozen=True)
class Written:
    """What ``write_profile`` wrote: the calibration version, the calibrated MJCF, the kept old profile and the
    profile file rewritten (a link's target)."""

    version: str
    mjcf: Path
    kept: Path
    profile: Path


def refuse_dropped_payload(path: Path, cell, wanted: tuple[str, ...]) -> None:
    """A fit without ``payload`` would write an MJCF without the payload that ``path``'s calibration carries
    (a full fit on the nominal model has no other place for it): refused before any record is read."""
    if "payload" in wanted:
        return
    held = JointTerms.from_profile(cell, path, "--write").payload_kg
    if held:
        raise CalibrationError(f"--params: leaves out payload, which {path}'s calibration carries ({held:.4g} kg): "
                               "the model written would lose it; add payload to --params, or re-fit single terms "
                               "with --only (which holds it)")


def check_write_target(path: Path, cell) -> None:
    """Before any record is read: ``path`` (a link: its target) is not a cell's installed profile
    (``_refuse_packaged``) nor a kept copy (``_refuse_kept_copy``), and the files a write adds beside it have names a
    file system takes, at most NAME_MAX bytes: the old profile kept as NAME.VERSION.yaml and the calibrated MJCF as
    NAME.DATE-cal-HASH.xml (a 300-character version failed only after the fit, in a traceback); nor a profile
    edited by hand that kept its version (``_refuse_edited_version``)."""
    _refuse_packaged(path, cell)  # naming the path given (a link's target is where it resolves)
    path = _target(path)
    data = read_bounded(path, "profile", ProfileError)
    version = _checked(path, cell, data)["version"]
    _refuse_kept_copy(path, str(version))
    kept = f"the old profile's copy {path.stem}.VERSION{path.suffix} (its version is {_bytes(version)} bytes)"
    for name, what, fix in ((kept_copy(path, version).name, kept, "give the profile a shorter version"),
                            (_mjcf(path, NEW_VERSION).name, f"the calibrated MJCF {path.stem}.DATE-cal-HASH"
                             ".xml", "give the profile a shorter file name")):
        if _bytes(name) > NAME_MAX:
            raise ProfileError(f"--write: {path}: the name of {what} would be {_bytes(name)} bytes, over the "
                               f"{NAME_MAX} a file name may have; {fix} (nothing written)")
    _refuse_edited_version(path, str(version), data)


def write_profile(path: Path, cell, result: dict, date: str, basis: bytes | None = None) -> Written:
    """Update ``path`` (``cell``'s profile) with ``result`` (from ``identify``); a new calibration version.

    The profile is checked whole (``parse_profile``) before anything is taken from it. A friction, damping or
    armature that came out below zero is not stored (CalibrationError naming it): no joint has one, and a
    run would simulate it. ``path`` a symbolic link: the file it points to is rewritten (the link stays a
    link to it), and the calibrated MJCF and the kept old profile go beside that file, where its ``model``
    and ``calibration`` name them. Read, rewrite and rename happen under an exclusive lock on the profile's
    folder: two writes at once lost one calibration while both reported a version. ``basis``: the profile's
    bytes the fit held its other terms at (``--only``); a profile changed since is refused, not rewritten. A
    ``date`` after tomorrow (UTC) is refused (``refuse_ahead``): a profile loads whatever its dates say, so it is
    here that a date from a clock that ran ahead is kept out."""
    refuse_ahead(date, "--write: the measured date", f"the records' clock ran ahead (or this host's is behind); {path} "
                 "not written")
    _refuse_packaged(path, cell)  # here too: a script's write, not only the command's
    path = _target(path)
    with _folder_locked(path.parent):
        return _write(path, cell, result, date, basis)


def _refuse_kept_copy(path: Path, version: str) -> None:
    """A kept copy (``NAME.VERSION.yaml`` of version VERSION, beside the ``NAME.yaml`` it was kept from) is what
    releases and records of that version are read from: rewritten in place, every release bound to it could no
    longer run (its bytes went to a name no one looks for). Refused: calibrate the profile it was kept from, or a copy of it under another name."""
    kept_from = path.with_name(path.name.removesuffix(f".{version}{path.suffix}") + path.suffix)
    if path.name.endswith(f".{version}{path.suffix}") and kept_from != path and kept_from.is_file():
        raise ProfileError(f"--write: {path} is the copy of version {version} kept when its profile was recalibrated "
                           f"(releases and records of that version read it); write the profile it was kept from, or "
                           f"copy it to another name first (nothing written)")


def _refuse_edited_version(path: Path, version: str, data: bytes) -> None:
    """The copy of ``version`` kept beside ``path`` (whose bytes are ``data``) differs from it: the profile was edited
    and kept its version string. Written on, the edit would go unkept (the copy is never overwritten) and the new
    calibration's ``previous`` would name the other document. Refused: give the edited profile a version of its own."""
    kept = kept_copy(path, version)
    if _is_file(kept, "kept profile") and read_bounded(kept, "profile", ProfileError) != data:
        raise ProfileError(f"--write: {path} is version {version}, but the copy of version {version} kept beside it "
                           f"({kept.name}) differs: the profile was edited and kept its version; give it a version "
                           "of its own (nothing written)")


def _refuse_other_version(target: Path, data: bytes, what: str, version: str) -> None:
    """A ``what`` of the new ``version`` already at ``target`` with other bytes (edited by hand, or the id's eight hex
    digits met another document's): reusing the id would name two different calibrations. Refused, naming it."""
    if _is_file(target, what) and read_bounded(target, what, ProfileError) != data:
        raise ProfileError(f"--write: the {what} {target} of version {version} exists with other contents; that "
                           "version names another calibration: move it away or restore it (nothing written)")


def _refuse_packaged(path: Path, cell) -> None:
    """A profile inside an installed package (cellguard's, or the package of a plugin's cell) is a cell's stock one,
    which every run of that cell on this install reads: calibrated in place, each ran the calibration without any
    scenario naming it. Refused (its real path: a link or a folder link is followed): write a copy of it."""
    real = Path(os.path.realpath(path))
    for package in dict.fromkeys(("cellguard", type(cell).__module__.partition(".")[0])):
        for folder in getattr(sys.modules.get(package), "__path__", ()):
            if real.is_relative_to(os.path.realpath(folder)):
                shown = f"{path} (a link to {real})" if Path(path).absolute() != real else str(path)
                raise ProfileError(f"--write: {shown} is in the installed package {package} ({folder}): a cell's "
                                   f"own profile, which every run of the cell here reads; copy it to another "
                                   f"folder and write the copy (a scenario's calibration: COPY runs with it; "
                                   f"nothing written)")


def _target(path: Path) -> Path:
    """The file a write of ``path`` rewrites: a link's target (the link stays), else ``path``."""
    path = Path(path)
    return path.resolve() if path.is_symlink() else path


def _mjcf(path: Path, version: str) -> Path:
    """``NAME.VERSION.xml`` beside the profile ``path``: its calibrated MJCF."""
    return path.with_name(f"{path.stem}.{version}.xml")


def _folder_locked(folder: Path):
    """An exclusive lock on the profile's ``folder`` while the block runs (a second writer waits): on the folder, not
    a lock file, it does not move with the profile's rename. No locks there (NFS without its daemon) is refused."""
    def refused(doing: str, exc: OSError) -> ProfileError:
        advice = "; write the profile on a local disk and copy it" if doing == "lock" else ""
        return ProfileError(f"--write: cannot {doing} the profile's folder {folder} ({exc.strerror}){advice}")

    return folder_locked(folder, refused)


def _write(path: Path, cell, result: dict, date: str, basis: bytes | None) -> Written:
    old_bytes = read_bounded(path, "profile", ProfileError)
    if basis is not None and old_bytes != basis:
        raise CalibrationError(f"--write: {path} changed while the re-fit ran (another calibration was written); "
                               "the terms it held are no longer the profile's: run identify --only again")
    raw = _checked(path, cell, old_bytes)
    _refuse_kept_copy(path, str(raw.get("version", "unversioned")))
    _refuse_edited_version(path, str(raw.get("version", "unversioned")), old_bytes)
    new = [e for e in result["estimates"] if e["parameter"] in WRITTEN and e["interval"] is not None]
    if not new:
        unexcited = [f"{e['joint']} {e['parameter']}" for e in result["estimates"] if e["parameter"] in WRITTEN]
        why = f": {', '.join(unexcited)} not excited by these records" if unexcited else ""
        raise CalibrationError(f"--write: nothing identified to write (of {', '.join(WRITTEN)}){why}; {path} not "
                               "written")
    negative = negative_values(new)
    if negative:
        raise CalibrationError(f"--write: {'; '.join(describe_value(e) for e in negative)}: below zero, which no "
                               f"joint has; not written to {path}")
    records = list(result["records"])
    method = f"{IDENTIFIED}{', '.join(records)} (regression on mj_inverse)"
    replaced = {(e["joint"], e["parameter"]) for e in new}
    measured = [m for m in raw.get("measured") or [] if (m.get("joint"), m.get("parameter")) not in replaced]
    for e in new:
        lo, hi = e["interval"]
        measured.append({"joint": e["joint"], "parameter": e["parameter"], "value": f"{e['value']:.6g} {e['unit']}",
                         "measured": date, "method": f"{method}; 95 % simultaneous interval [{lo:.6g}, {hi:.6g}] "
                                                     f"{e['unit']}"})
    old_version = str(raw.get("version", "unversioned"))
    raw["measured"] = measured
    draft = parse_profile(cell.model, dump_yaml(raw).encode(), str(path))
    mjcf = calibrated_mjcf(cell, JointTerms.of_profile(cell, draft, _payload(result)))
    # the whole document it records (limits too: a hand-edited limit under a kept version made the same id twice)
    recorded = {key: value for key, value in raw.items() if key not in ("version", "model", "calibration")}
    digest = hashlib.sha256(json.dumps([recorded, date, records, old_version, mjcf], sort_keys=True,
                                       default=str).encode()).hexdigest()[:8]
    version = f"{date}-cal-{digest}"
    mjcf_path = _mjcf(path, version)
    raw["version"] = version
    raw["model"] = mjcf_path.name
    raw["calibration"] = {"version": version, "mjcf": mjcf_path.name, "date": date, "records": records,
                          "previous": old_version}
    text = dump_yaml(raw)
    parse_profile(mujoco.MjModel.from_xml_string(mjcf), text.encode(), str(path))  # loads on its own model
    kept = kept_copy(path, old_version)
    _refuse_other_version(mjcf_path, mjcf.encode(), "calibrated MJCF", version)
    _refuse_other_version(kept_copy(path, version), text.encode(), "kept profile", version)
    added = []
    try:
        # an older version already kept there is never overwritten; a folder there fails here, before the profile
        for target, data, what in ((kept, old_bytes, "previous profile"), (mjcf_path, mjcf, "calibrated MJCF")):
            if not _is_file(target, what):
                write_output(target, data, what)
                added.append(target)
        write_output(path, text, "profile")
    except OutputError:
        for target in added:  # the command failed: leave the folder as it was
            target.unlink(missing_ok=True)
        raise
    return Written(version, mjcf_path, kept, path)


def _checked(path: Path, cell, data: bytes) -> dict:
    """The profile at ``path`` (its bytes ``data``) as YAML, checked whole before anything is taken from it: of
    ``cell``'s robot (CalibrationError naming both), then every field."""
    raw = parse_yaml(data, str(path), ProfileError)
    if not isinstance(raw, dict) or raw.get("robot") != cell.profile.robot:
        robot = raw.get("robot") if isinstance(raw, dict) else None
        raise CalibrationError(f"--write: {path} is a profile of robot {robot!r}; the records are of "
                               f"{cell.profile.robot!r} ({cell.name})")
    parse_profile(cell.model, data, str(path))
    return raw


def _bytes(name: str) -> int:
    return len(os.fsencode(name))


def _is_file(path: Path, what: str) -> bool:
    """Whether ``path`` (a ``what``) is a file; OutputError naming it where it cannot be looked at (a name over
    NAME_MAX bytes, no access), where ``Path.is_file`` raises OSError."""
    try:
        return path.is_file()
    except OSError as exc:
        raise OutputError(f"{what} {path}: cannot write ({exc.strerror or exc}); nothing written") from None


def _payload(result: dict) -> float:
    """The payload [kg] the calibrated MJCF carries: the one fitted, only where its interval lies above zero (an
    estimate within noise of none is no mass at all); else the one the fit held (``--only`` holds the
    calibration's: dropping it would leave the model the re-fitted terms were not estimated on)."""
    fitted = [e for e in result["estimates"] if e["parameter"] == "payload" and e["interval"] is not None]
    if fitted:
        return fitted[0]["value"] if fitted[0]["interval"][0] > 0.0 else 0.0
    return float(result.get("payload_held_kg", 0.0))
