"""Release bundles: a manifest freezing everything that decides how a policy behaves on a cell.

The manifest holds the policy's content hash (weights files, program source or server metadata,
as its adapter computes it), the action map's bytes hash, the embodiment profile with its
calibration version, a calibrated profile of it when ``--profile`` names one (its path, sha256 and
version: the stages' runs take the file that still holds those bytes as their scenario's ``calibration``),
the envelope settings and the cellguard version. The release id is the
sha256 of the manifest's canonical JSON (sorted keys, no spaces), so identical inputs give the
same id and an edited manifest no longer matches its id.
"""

from __future__ import annotations

import hashlib
import json
import re
import shlex
from collections.abc import Iterator
from dataclasses import dataclass
from importlib.metadata import PackageNotFoundError, distribution
from pathlib import Path
from urllib.parse import quote

from cellguard import __version__
from cellguard.control.config import GuardConfig
from cellguard.control.settings import build_guard
from cellguard.embodiment.profile import calibrated_profile, kept_copy
from cellguard.errors import CellguardError, ConfigError, ExtraMissing, ProfileError, ScenarioError, UnknownNameError
from cellguard.output import not_regular
from cellguard.release.errors import BundleMismatch, ReleaseError
from cellguard.robot.registry import CELLS, cell_names, make_cell
from cellguard.scenario import parse_scenario
from cellguard.yaml_file import read_bounded, read_yaml

ID_CHARS = 16  # hex characters of the sha256 shown as the release id


def canonical_json(value) -> bytes:
    """The one byte form that is hashed: sorted keys, no whitespace, UTF-8."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), ensure_ascii=False).encode()


def sha256_file(path: Path, what: str) -> str:
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError as exc:
        raise ReleaseError(f"{what} {path}: cannot read ({exc.strerror or exc.__class__.__name__})") from None


def yaml_sha256(path: Path, what: str) -> str:
    """A frozen YAML input's hash (the action map, a calibration), read as every YAML input is: a FIFO, a device
    or a file over the limit is one line (it was read whole before any check: ``/dev/zero`` filled the memory,
    a FIFO waited forever)."""
    return hashlib.sha256(read_bounded(path, what, ReleaseError)).hexdigest()


@dataclass(frozen=True)
class Bundle:
    """A frozen release: ``manifest`` (plain JSON) and its id (``sha256(canonical_json)[:16]``)."""

    id: str
    manifest: dict

    @property
    def cell(self) -> str:
        return self.manifest["profile"]["cell"]

    @property
    def policy_spec(self) -> str:
        """The scenario ``policy:`` string, the action map attached as ``?map=``."""
        spec, amap = self.manifest["policy"]["spec"], self.manifest["action_map"]
        if amap is None:
            return spec
        return f"{spec}{'&' if '?' in spec else '?'}map={quote(amap['path'])}"  # a path's & % # kept as written

    @property
    def calibration(self) -> str | None:
        """The calibrated profile's path as frozen (a manifest from before calibrations has none); the runs take
        the file that holds its bytes now (``calibration_file``)."""
        calibration = self.manifest.get("calibration")
        return calibration["path"] if calibration else None

    @property
    def guard(self) -> GuardConfig:
        return GuardConfig.model_validate(self.manifest["envelope"])

    def short(self) -> dict:
        """What a record's context and the log say about this release."""
        return {"id": self.id, "policy": self.manifest["policy"]["spec"],
                "policy_sha256": self.manifest["policy"]["sha256"], "note": self.manifest.get("note", "")}


def release_id(manifest: dict) -> str:
    return hashlib.sha256(canonical_json(manifest)).hexdigest()[:ID_CHARS]


def create_bundle(policy: str, action_map: Path | None, profile: str, envelope: Path | None, note: str = "") -> Bundle:
    """Freeze the inputs into a manifest; every file is read and checked (a bad one names itself)."""
    cell_name, profile_path = _resolve_profile(profile)
    cell = make_cell(cell_name)
    prof, calibrated = cell.profile, _calibration(cell, profile_path)  # the cell's own, and a calibration of it
    settings = _envelope(envelope, cell)
    amap = None
    if action_map is not None:
        _check_takes_map(policy)
        path = Path(action_map).resolve()
        amap = {"path": str(path), "sha256": yaml_sha256(path, "action map")}
    manifest = {
        "format": 1,
        "policy": {"spec": _absolute_spec(policy), "sha256": ""},
        "action_map": amap,
        "profile": {"cell": cell_name, "robot": prof.robot, "version": prof.version, "sha256": prof.sha256,
                    "calibration_version": calibration_version(prof)},
        "envelope": settings.model_dump(mode="json"),
        "cellguard": __version__,
        "note": note,
    }
    if calibrated is not None:  # only then: a release on the cell's own profile keeps the id it had before
        manifest["calibration"] = {"path": str(profile_path), "sha256": calibrated.sha256,
                                   "version": calibrated.version}
    manifest["policy"]["sha256"] = policy_hash(Bundle("", manifest))
    return Bundle(release_id(manifest), manifest)


def verify_bundle(bundle: Bundle, policy=None, profile=None, calibration: bool = True) -> None:
    """Raise BundleMismatch, one line naming the input, if anything frozen has changed since create.

    ``policy``: the release's policy as a run has loaded it (its adapter hashed what it loaded), compared
    instead of loading the policy again: a file swapped between two runs of a stage is caught there.
    ``profile``: the profile the run's robot took, compared with the release's calibration the same way.
    ``calibration`` False: the release's calibration is not checked, for a release whose policy drives a robot
    that runs on another's (the incumbent in a shadow run, on the candidate's)."""
    if release_id(bundle.manifest) != bundle.id:
        raise BundleMismatch(f"release {bundle.id}: manifest edited (hashes to {release_id(bundle.manifest)})")
    changed = next(_changes(bundle, policy, profile, calibration), None)
    if changed is not None:
        raise changed.error


@dataclass(frozen=True)
class Changed:
    """A frozen input that does not hash now as ``release create`` froze it: ``error`` is what ``verify_bundle``
    raises for it, naming it and both hashes. ``reason``: "changed" (tampering, or an edit), "upgraded" (a hash
    cellguard computes from its own code, made by another version: not tampering) or "unreadable" (``now`` None;
    ``cause`` says why)."""

    release: str
    input: str  # "action map", "profile", "calibration" or "policy"
    what: str  # the input in words, with its file, cell or policy spec
    frozen: str
    now: str | None
    error: ReleaseError
    reason: str = "changed"
    cause: str = ""

    def __str__(self) -> str:
        """One line naming the release, the input, why, and the frozen hash."""
        if self.reason == "unreadable":
            return (f"release {self.release}: {self.what} cannot be read ({self.cause}; frozen sha256 "
                    f"{self.frozen[:12]})")
        return str(self.error)

    def to_dict(self) -> dict:
        return {"release": self.release, "input": self.input, "what": self.what, "sha256": self.now,
                "frozen": self.frozen, "problem": str(self)}


REASONS = {"changed": "changed since create", "unreadable": "cannot be read", "upgraded": "made by another cellguard"}


@dataclass(frozen=True)
class InputsChecked:
    """What ``release verify`` found of the files frozen by the releases a stage can run (current or last_good)."""

    releases: tuple[str, ...]  # checked
    changed: tuple[Changed, ...]  # each a problem, whatever its reason
    unchecked: tuple[str, ...]  # each input not checked here, in words (a served policy, an extra not installed)
    idle: int  # releases neither current nor last_good anywhere: not checked (their files may be gone, rightly)

    def by_reason(self, reason: str) -> list[Changed]:
        return [c for c in self.changed if c.reason == reason]

    def to_dict(self) -> dict:
        return {"checked": list(self.releases), **{r: [c.to_dict() for c in self.by_reason(r)] for r in REASONS},
                "not_checked": list(self.unchecked), "idle_not_checked": self.idle}


def check_live_inputs(store) -> InputsChecked:
    """Hash again, here and contacting nothing, what each release current or last_good at some stage froze (a
    rollback or the line runs it: ``promote`` and ``run`` re-hash only the release they take, so a policy file
    swapped under production's release showed nowhere). A bundle edited or gone is ``verify_log``'s to name."""
    named = {rid for p in store.all_pointers() for rid in (p.current, p.last_good) if rid is not None}
    stored = store.bundle_ids()
    checked, changed, unchecked = [], [], []
    for rid in sorted(named & stored):
        try:
            bundle = store.bundle(rid)
        except ReleaseError:  # edited: verify_log names it
            continue
        served = _unchecked_policy(bundle)
        checked.append(rid)
        found, missing = _offline_changes(bundle, served is not None)
        changed += found
        unchecked += [served] if served else []
        unchecked += missing
    return InputsChecked(tuple(checked), tuple(changed), tuple(unchecked), len(stored - named))


def _offline_changes(bundle: Bundle, served: bool) -> tuple[list[Changed], list[str]]:
    """Every input of ``bundle`` that does not hash as frozen, not the first only, and, in words, each that cannot
    be hashed here for want of what is not installed: its cell's plugin or extra (the profile and the policy need
    the cell: the SO-101's model without ``cellguard[so101]``), or the extra its policy's source imports (``lerobot``
    without ``cellguard[lerobot]``). Those are not problems: the release runs where they are installed."""
    found, missing, spec = [], [], bundle.manifest["policy"]["spec"]
    try:
        for changed in _changes(bundle, served=served):
            found.append(changed)
    except (UnknownNameError, ExtraMissing) as exc:  # a plugin's cell, its plugin not installed here; or its extra
        needs = f"cellguard[{exc.extra}]" if isinstance(exc, ExtraMissing) else f"the plugin of cell {bundle.cell!r}"
        found += _calibration_changes(bundle, None)
        missing.append(f"release {bundle.id}: profile of {bundle.cell!r}{'' if served else f' and policy {spec}'}: "
                       f"not checked here (needs {needs}: {exc})")
    except CellguardError as exc:
        found += _calibration_changes(bundle, None)
        found.append(Changed(bundle.id, "profile", f"profile of {bundle.cell!r}", bundle.manifest["profile"]["sha256"],
                             None, ReleaseError(str(exc)), "unreadable", f"its cell does not load: {exc}"))
    unread = [c for c in found if c.input == "policy" and c.reason == "unreadable"]
    needs = _not_installed(spec.partition(":")[0]) if unread else []
    if needs:  # the policy did not load, and its source's extra is not installed here
        found.remove(unread[0])
        missing.append(f"release {bundle.id}: policy {spec}: not checked here (needs {', '.join(needs)}, not installed "
                       f"here: {unread[0].cause})")
    return found, missing


def _not_installed(extra: str) -> list[str]:
    """The packages of ``cellguard[extra]`` (a policy source's extra is named as its scheme) not installed here, as
    cellguard's own metadata lists them; none when cellguard is not installed as a package."""
    try:
        requires = distribution("cellguard").requires or []
    except PackageNotFoundError:
        return []
    names = [re.match(r"[A-Za-z0-9._-]+", r).group() for r in requires
             if re.search(rf"extra\s*==\s*['\"]{re.escape(extra)}['\"]", r)]
    return [name for name in names if not _installed(name)]


def _installed(name: str) -> bool:
    try:
        distribution(name)
    except PackageNotFoundError:
        return False
    return True


def _unchecked_policy(bundle: Bundle) -> str | None:
    """Why ``release verify`` does not hash the release's policy, in words, or None: a served policy (its source takes
    an address, neither a file nor nothing) hashes what its server sends, and a source whose module does not import
    here cannot load it."""
    from cellguard.policy.registry import source, takes_nothing

    spec = bundle.manifest["policy"]["spec"]
    try:
        module = source(spec.partition(":")[0])
    except CellguardError as exc:
        return f"release {bundle.id}: policy {spec}: not checked here ({exc})"
    if module.TAKES_FILE or takes_nothing(module):
        return None
    return f"release {bundle.id}: policy {spec}: not checked offline (served policy)"


def _changes(bundle: Bundle, policy=None, profile=None, calibration: bool = True,
             served: bool = False) -> Iterator[Changed]:
    """Each frozen input that no longer hashes as frozen, in ``verify_bundle``'s order, lazily (it stops at the
    first); ``served``: the policy is not loaded (its server is not contacted)."""
    m = bundle.manifest
    if m["action_map"] is not None:
        path = m["action_map"]["path"]
        yield from _compare(bundle, "action map", f"action map {path}", m["action_map"]["sha256"],
                            lambda: yaml_sha256(Path(path), "action map"))
    cell = make_cell(bundle.cell)
    built_in = bundle.cell in CELLS  # its profile ships with cellguard
    yield from _compare(bundle, "profile", f"profile of {bundle.cell!r}", m["profile"]["sha256"],
                        lambda: cell.profile.sha256, built_in)
    if calibration:
        yield from _calibration_changes(bundle, profile)
    if not served:
        yield from _compare(bundle, "policy", f"policy {m['policy']['spec']}", m["policy"]["sha256"],
                            lambda: policy_hash(bundle, cell) if policy is None else policy.content_hash(),
                            built_in and _taught(m["policy"]["spec"]))


def _taught(spec: str) -> bool:
    """Whether the policy ``spec`` is a cell's taught program (a source taking nothing: ``scripted``), whose hash is
    of its code; False for a source that does not load here (its hash cannot be had either)."""
    from cellguard.policy.registry import source, takes_nothing

    try:
        return takes_nothing(source(spec.partition(":")[0]))
    except CellguardError:
        return False


def _compare(bundle: Bundle, kind: str, what: str, frozen: str, sha256, own_code: bool = False) -> Iterator[Changed]:
    """``what`` as a Changed when ``sha256()``, its hash now, is not ``frozen``, or cannot be had (its error, whose
    cause is the input's own words). ``own_code``: the hash is of cellguard's own code or files, so another
    version's is not tampering: an upgrade since create is said as such (the release is still refused)."""
    try:
        now = sha256()
    except ReleaseError as exc:
        cause = str(exc.__cause__ or exc).removeprefix(f"release {bundle.id}: ")
        yield Changed(bundle.id, kind, what, frozen, None, exc, "unreadable", cause)
        return
    if now == frozen:
        return
    hashes, made_by = f"(sha256 {now[:12]}, frozen {frozen[:12]})", bundle.manifest.get("cellguard")
    if own_code and made_by != __version__:
        yield Changed(bundle.id, kind, what, frozen, now, BundleMismatch(
            f"release {bundle.id}: {what}: cellguard upgraded ({made_by} -> {__version__}) since create: re-create "
            f"the release {hashes}"), "upgraded")
        return
    yield Changed(bundle.id, kind, what, frozen, now, BundleMismatch(
        f"release {bundle.id}: {what} changed since create {hashes}"))


def policy_hash(bundle: Bundle, cell=None) -> str:
    """The content hash the policy's own adapter reports (weights, program, server metadata)."""
    from cellguard.policy.registry import make_policy

    cell = cell if cell is not None else make_cell(bundle.cell)
    try:
        policy = make_policy(bundle.policy_spec, cell)
    except CellguardError as exc:  # at create, what --policy gave; later, what the release froze (never edited)
        if not bundle.id:
            raise ReleaseError(f"--policy: {exc}") from None
        raise ReleaseError(f"release {bundle.id}: its policy (create a new release to change it): "
                           f"{_frozen(bundle, exc)}") from exc  # its cause: the policy's own words (verify)
    try:
        return policy.content_hash()
    finally:
        close = getattr(policy, "close", None)
        if close is not None:
            close()


def _frozen(bundle: Bundle, exc: CellguardError) -> str:
    """Why the release's policy does not load, as what can be done: a source that states no step period
    (``adapter.step_period``'s refusal) needs a new release whose policy gives it, as its own refusal's ``give
    ?dt=SECONDS`` cannot be done to a frozen release: the ``release create`` that makes it, with this release's
    other inputs as its manifest holds them (the file holding the calibration it runs on, ``calibration_file``: a
    copy kept after an in-place recalibration, else its cell; the action map's path; the envelope's settings that
    are not the defaults, as it holds no envelope file; its note). Without them the command suggested was refused
    for a missing --profile; without the note it made another id, and after a recalibration it bound the new one."""
    from cellguard.policy.adapter import StepPeriodUnstated

    if not isinstance(exc, StepPeriodUnstated):
        return str(exc)
    m = bundle.manifest
    spec = m["policy"]["spec"]
    timed = spec + ("&" if "?" in spec else "?") + "dt=SECONDS"
    notes = ["SECONDS: the policy's control period, e.g. 0.0667 for 15 Hz"]
    try:
        profile = calibration_file(bundle)
    except BundleMismatch as gone:
        profile = Path(bundle.calibration)
        notes.append(str(gone).partition(": ")[2])
    args = ["--policy", timed, "--profile", bundle.cell if profile is None else str(profile)]
    args += ["--map", m["action_map"]["path"]] if m.get("action_map") else []
    args += ["--note", m["note"]] if m.get("note") else []
    defaults = GuardConfig().model_dump(mode="json")
    envelope = {k: v for k, v in (m.get("envelope") or {}).items() if defaults.get(k) != v}
    if envelope:
        args += ["--envelope", "FILE"]
        notes.append(f"FILE: a YAML file holding this release's envelope, {json.dumps(envelope)}")
    return (f"policy: {spec}: the step period is not stated and a frozen release cannot take ?dt=: cellguard release "
            f"create {shlex.join(args)} ({'; '.join(notes)})")


def calibration_version(profile) -> str:
    """A short stamp of what was measured on the robot, and when (changes with every recalibration)."""
    measured = sorted((m.joint, m.parameter, m.value, m.measured, m.method) for m in profile.measured)
    return hashlib.sha256(canonical_json([profile.version, measured])).hexdigest()[:12]


def _calibration(cell, path: Path | None):
    """The profile at ``path`` when it is a calibration of the cell's own (``identify --write``), checked as a
    scenario's ``calibration:`` is: same robot, joints and limits. None for the cell's own profile. Other limits
    are refused: the envelope and the gates are the cell's, so its own profile must change first."""
    if path is None:
        return None
    try:
        prof = calibrated_profile(cell.model, cell.profile, path)
    except ProfileError as exc:
        raise ReleaseError(f"--profile: {exc}; a release runs on the cell's own profile (--profile {cell.name}) "
                           f"or on a calibration of it (`cellguard identify --write` writes one): change the "
                           f"cell's own profile for other joints or limits") from None
    return None if prof.sha256 == cell.profile.sha256 else prof


def calibration_file(bundle: Bundle) -> Path | None:
    """The file that holds the calibration the release binds, found by its bytes: the path frozen or, recalibrated
    in place since (``identify --write`` rewrites the profile), the old profile it kept beside it (a link's target)
    as NAME.VERSION.yaml, with the calibrated MJCF that calibration names. Bound by path, a release stopped
    running at the next recalibration, and so did a rollback to it. BundleMismatch naming both when neither
    holds it; None without a calibration."""
    frozen = bundle.manifest.get("calibration")
    if frozen is None:
        return None
    path = Path(frozen["path"])
    looked = [path, kept_copy(path, frozen["version"])]
    held = []
    for candidate in looked:
        sha256, what = _held(candidate)
        if sha256 == frozen["sha256"]:
            return candidate
        held.append(what)
    raise BundleMismatch(f"release {bundle.id}: calibration {path} changed since create and no copy of it is kept "
                         f"({'; '.join(held)}; frozen: version {frozen['version']}, sha256 {frozen['sha256'][:12]})")


def _held(path: Path) -> tuple[str | None, str]:
    """The sha256 of the calibration file ``path`` and, in words, what it holds (or why it cannot be read)."""
    try:
        sha256 = yaml_sha256(path, "calibration")
    except ReleaseError as exc:
        return None, str(exc)
    return sha256, f"{path}: sha256 {sha256[:12]}"


def _calibration_changes(bundle: Bundle, loaded) -> Iterator[Changed]:
    """The calibrated profile the release binds as a Changed if it is not what ``create`` hashed (``loaded``: the
    profile a run's robot took; else the file that holds it is looked for again), as for the action map and the
    policy."""
    frozen = bundle.manifest.get("calibration")
    if frozen is None:
        return
    what = f"calibration {frozen['path']}"
    if loaded is not None:
        yield from _compare(bundle, "calibration", what, frozen["sha256"], lambda: loaded.sha256)
        return
    try:
        calibration_file(bundle)
    except BundleMismatch as exc:
        now, held = _held(Path(frozen["path"]))
        yield Changed(bundle.id, "calibration", what, frozen["sha256"], now, exc, "changed" if now else "unreadable",
                      held)


def _resolve_profile(profile: str) -> tuple[str, Path | None]:
    """``--profile`` is a profile YAML file (its ``robot:`` names the cell) or a registered cell's name."""
    path = Path(profile)
    if path.is_file():
        raw = read_yaml(path, "profile", ReleaseError)
        robot = raw.get("robot") if isinstance(raw, dict) else None
        cells = cell_names()
        if not isinstance(robot, str) or robot not in cells:
            raise ReleaseError(f"--profile {path}: robot {robot!r} is not a registered cell; cells: {', '.join(cells)}")
        return str(robot), path.resolve()
    cells = cell_names()
    if profile in cells:
        return profile, None
    raise ReleaseError(f"--profile {profile}: neither a profile file nor a cell; cells: {', '.join(cells)}")


def _envelope(path: Path | None, cell) -> GuardConfig:
    """The envelope file read as a scenario's ``guard:`` section, by the scenario's own checks, and the guard built
    on ``cell`` as every stage's run builds it (``build_guard``: a box in another unit, settings leaving out the home
    pose): a rule of create's own let ``.inf`` or a document ``[]`` through, and a box in centimetres was released
    and promoted to fail only at each run."""
    if path is None:
        return GuardConfig()
    raw = read_yaml(Path(path), "envelope", ReleaseError)
    try:
        settings = parse_scenario({"cell": cell.name, "guard": raw}, origin=f"--envelope {path}").guard
        build_guard(cell, settings)
    except ScenarioError as exc:
        raise ReleaseError(str(exc)) from None
    except ConfigError as exc:
        raise ReleaseError(f"--envelope {path}: {exc}") from None
    return settings


def _absolute_spec(spec: str) -> str:
    """A policy file named relative to here is frozen by its absolute path (its source declares ``TAKES_FILE``); a
    FIFO, device or socket there is refused before its adapter waits on it or calls it missing; a source that takes
    nothing is stored without its empty argument."""
    from cellguard.policy.registry import takes_nothing

    scheme, sep, arg = spec.partition(":")
    source = _source(scheme)
    _refuse_map_option(source, scheme, arg)
    if sep and not arg and takes_nothing(source):  # ``scripted:`` is ``scripted``: one release of one program
        return scheme
    if source.TAKES_FILE and sep:
        target, q, query = arg.partition("?")
        path = Path(target).resolve()
        try:
            kind = not_regular(path)
        except OSError as exc:  # a name too long, no access
            raise ReleaseError(f"--policy {target}: cannot be read ({exc.strerror or exc})") from None
        if kind is not None:
            raise ReleaseError(f"--policy {target}: is {kind}, not a regular file")
        return f"{scheme}:{path}{q}{query}"
    return spec


def _source(scheme: str):
    """The module of the policy source ``scheme`` (``registry.SCHEMES``), which declares what it takes."""
    from cellguard.policy.registry import source

    try:
        return source(scheme)
    except CellguardError as exc:
        raise ReleaseError(f"--policy: {exc}") from None


def _check_takes_map(spec: str) -> None:
    """--map is given to the policy as its ``?map=`` option (``Bundle.policy_spec``): refused here for a policy
    without one, which named the joined text as an unknown policy source the user never typed."""
    from cellguard.policy.registry import SCHEMES

    scheme = spec.partition(":")[0]
    if "map" not in _source(scheme).OPTIONS:
        mapped = [s for s in SCHEMES if _takes_map(s)]
        raise ReleaseError(f"--map: the {scheme} policy drives the robot's joints directly; it takes no action map "
                           f"(the {', '.join(mapped)} policies do)")


def _takes_map(scheme: str) -> bool:
    """Whether the source ``scheme`` takes an action map; False when its extra is not installed here."""
    try:
        return "map" in _source(scheme).OPTIONS
    except ReleaseError:
        return False


def _refuse_map_option(source, scheme: str, arg: str) -> None:
    """An action map given as a policy option is used unhashed: it goes with --map. The adapter's own parser
    decides what is an option (``?ma%70=`` is ``map`` once decoded; the text ``map=`` was checked)."""
    from cellguard.policy.adapter import split_options

    if "map" not in source.OPTIONS:
        return
    try:
        _, options = split_options(arg, source.OPTIONS, scheme)
    except CellguardError as exc:
        raise ReleaseError(f"--policy: {exc}") from None
    if "map" in options:
        raise ReleaseError("--policy: give the action map with --map, not ?map=")
