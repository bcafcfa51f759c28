"""Incident replay: re-run a recorded cycle's chunks through the simulator and compare with the record.

The chunks recorded in cycle N go through a fresh guard (the run's own settings) into the simulated
cell, started from the recorded state at the cycle's start, with the cell's task set up for cycle N
(the part at the fixture). The model is the nominal MJCF or the calibrated one (a profile's measured
friction, damping and armature, as ``identify --write`` leaves them): by default the profile the record was
made with (its sha256 is in the record's context), found where its run read it (the absolute file the context
names, from any working folder) or, gone from there, taken from the profile document the context holds; the
result names the profile it used and says so when that is not the record's (a newer calibration, or an older
record's profile not found). The
simulated joint positions and currents are sampled at the recorded ticks' times (any rate: a production
record's 50 Hz stream will do). With a ``Vary`` (``friction:elbow=0.8..1.6``) the factor on that parameter
that best reproduces the recorded currents is searched: a grid over the range, then a bounded scalar search
around the best grid point. This is how a technician checks a hypothesis before touching the robot.
"""

from __future__ import annotations

import hashlib
import os
import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import mujoco
import numpy as np
from scipy.optimize import minimize_scalar

from cellguard.calibrate.identify import CalibrationError
from cellguard.calibrate.torque_model import JointTerms, hinge_joints
from cellguard.embodiment.profile import kept_copy

VARIED = ("friction", "damping", "armature")
GRID = 5  # factors tried across the range before the bounded search
DOCUMENT = "the record's own document"  # where the profile's terms came from when its file is gone
_TERMS = ("torque", "force", "damping", "inertia", "mass")  # the dimensions of friction, damping and armature
XTOL = 0.01  # the search stops when the factor is known to this [1]
_FACTOR = r"(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][-+]?[0-9]+)?"  # 2, 2., .5, 8e-1: the range is checked apart
_VARY = re.compile(rf"^(?P<param>\w+):(?P<joint>\w+)=(?P<low>{_FACTOR})\.\.(?P<high>{_FACTOR})$")


@dataclass(frozen=True)
class Vary:
    """Search ``parameter`` of ``joint`` as a factor on the model's value, in [low, high]."""

    parameter: str
    joint: str
    low: float
    high: float


def parse_vary(text: str, cell) -> Vary:
    """``friction:elbow=0.8..1.6`` -> a ``Vary`` for ``cell``; CalibrationError naming what is allowed."""
    m = _VARY.match(text.strip())
    joints = [cell.profile.joint_names[i] for i in hinge_joints(cell)]
    if m is None:
        raise CalibrationError(f"--vary: {text!r} is not PARAM:JOINT=LOW..HIGH (e.g. friction:elbow=0.8..1.6)")
    param, joint = m["param"], m["joint"]
    if param not in VARIED:
        raise CalibrationError(f"--vary: {param!r} is not a parameter replay can vary; allowed: {', '.join(VARIED)}")
    if joint not in joints:
        kinds = {j.name: j.kind for j in cell.profile.joints}
        what = (f"is a {kinds[joint]} joint of the {cell.name} model; replay varies hinge joints only (the joints "
                f"identify measures, whose currents the replay compares)" if joint in kinds
                else f"is not a joint of the {cell.name} model")
        raise CalibrationError(f"--vary: {joint!r} {what}; allowed: {', '.join(joints)}")
    low, high = float(m["low"]), float(m["high"])  # ``_FACTOR``: each a number float() reads
    if not 0.0 < low < high <= 20.0:
        raise CalibrationError(f"--vary: range {low}..{high} must satisfy 0 < LOW < HIGH <= 20")
    return Vary(param, joint, low, high)


@dataclass(frozen=True)
class Trajectory:
    """``t`` (n,) [s] into the cycle; ``q`` (n, dof) [rad or m]; ``current`` (n, dof) [A]; ``q_cmd`` (n, dof)."""

    t: np.ndarray
    q: np.ndarray
    current: np.ndarray
    q_cmd: np.ndarray


@dataclass(frozen=True)
class RecordedCycle:
    """What replay needs of one recorded cycle."""

    cell: str
    seed: int
    cycle: int
    joints: tuple[str, ...]
    t_start_ns: int
    t_ns: np.ndarray  # (n,) recorded tick times in the cycle
    ticks: Trajectory
    qd0: np.ndarray  # (dof,) velocity at the first tick
    chunks: list  # RecordedChunk, in arrival order
    guard: dict  # the run's guard settings (scenario ``guard``)
    mount: str | None = None  # the record's context ``mount``: "stand" when the base was held (``excite --stand``)
    health: object = None  # the record's ``Health`` (a full read): a damaged record replays what was readable
    profile: dict = field(default_factory=dict)  # the record's context ``embodiment``: version, sha256, calibration,
    # the profile's document and the file it was read from (absolute; older records have neither)
    calibration_file: str | None = None  # the run's scenario ``calibration``, as typed: relative to the run's folder


def load_cycle(path: Path, cycle: int) -> RecordedCycle:
    """Cycle ``cycle`` of the record in ``path``: its ticks (every rate), its chunks, the run's settings, its
    mount, its profile (and the file the run read it from) and its health (what a full read found: the caller
    warns when the record is not whole)."""
    from cellguard.record.reader import open_record

    with open_record(path) as rec:
        health = rec.health()
        ctx = rec.context
        cycles = {c.cycle: c for c in rec.cycles()}
        if cycle not in cycles:
            known = f"0..{max(cycles)}" if cycles else "none"
            raise CalibrationError(f"--cycle: {cycle} is not a finished cycle of {path} (cycles {known})")
        c = cycles[cycle]
        ticks = rec.ticks(rate="all", start_ns=c.t_start_ns, end_ns=c.t_end_ns)
        chunks = [ch for ch in rec.chunks() if c.t_start_ns <= ch.t_received_ns <= c.t_end_ns]
    if len(ticks) < 2 or not chunks:
        raise CalibrationError(f"--cycle: cycle {cycle} of {path} has {len(ticks)} ticks and {len(chunks)} chunks "
                               "recorded; replay needs both")
    if ctx.get("mount") not in (None, "stand"):
        raise CalibrationError(f"{path}: the record's context says mount {ctx.get('mount')!r}; replay simulates a "
                               f"free cell or one on a stand")
    scenario = ctx.get("scenario") or {}
    t = (ticks.t_ns - c.t_start_ns) * 1e-9
    return RecordedCycle(ctx.get("cell"), int(scenario.get("seed", 0)), cycle, tuple(ticks.joints), c.t_start_ns,
                         ticks.t_ns, Trajectory(t, ticks.q_meas, ticks.current, ticks.q_cmd), ticks.qd_meas[0],
                         chunks, scenario.get("guard") or {}, ctx.get("mount"), health, ctx.get("embodiment") or {},
                         calibration if isinstance(calibration := scenario.get("calibration"), str) else None)


def simulate(rc: RecordedCycle, terms: JointTerms, vary: Vary | None = None, factor: float = 1.0) -> Trajectory:
    """Run ``rc``'s chunks through a fresh guard into the cell with ``terms`` (``vary``'s term x ``factor``),
    mounted on a stand when the record's was (``rc.mount``)."""
    from cellguard.calibrate.stand import Stand
    from cellguard.control.settings import build_guard
    from cellguard.robot.protocol import SafetyInputs
    from cellguard.robot.registry import make_cell
    from cellguard.control.config import GuardConfig

    cell = make_cell(rc.cell, seed=rc.seed)
    _apply(cell, terms, vary, factor)
    if rc.mount == "stand":
        Stand().apply(cell)
    cell.begin_cycle(rc.cycle)
    d, drives = cell.data, cell.drives
    d.qpos[drives.qadr] = rc.ticks.q[0]
    d.qvel[drives.dadr] = rc.qd0
    drives.write(rc.ticks.q_cmd[0])
    mujoco.mj_forward(cell.model, d)
    guard = build_guard(cell, GuardConfig.model_validate(rc.guard))  # checked by ``_check_guard``
    guard.reset(rc.ticks.q[0])
    dt_ns = cell.dt_ns
    n = int((rc.t_ns[-1] - rc.t_start_ns) // dt_ns) + 1
    q, cur, cmd = (np.empty((n, len(rc.joints))) for _ in range(3))
    state = cell.read()
    q[0], cur[0], cmd[0] = state.q, state.current, rc.ticks.q_cmd[0]
    pending, safe = list(rc.chunks), SafetyInputs()
    for k in range(1, n):
        t = rc.t_start_ns + (k - 1) * dt_ns
        while pending and pending[0].t_received_ns <= t:
            ch = pending.pop(0)
            guard.push(_chunk(ch), t)
        setpoint, _ = guard.tick(t, state, safe)
        cmd[k] = cell.write(setpoint)
        cell.step()
        state = cell.read()
        q[k], cur[k] = state.q, state.current
    at = np.clip((rc.t_ns - rc.t_start_ns) // dt_ns, 0, n - 1).astype(int)
    return Trajectory(rc.ticks.t, q[at], cur[at], cmd[at])


def _check_guard(rc: RecordedCycle, cell, path: Path) -> None:
    """CalibrationError, one line naming the record and the setting, when this cellguard refuses the guard settings
    the record's run had (a check added since: a box beyond 100 m or with a wall over the tool's reach beyond where
    the tool gets, a soft_margin or a box leaving out the home pose), as a scenario's ``guard:`` is refused: replay
    cannot build the guard that ran.
    A box in millimetres recorded before the reach checks ended in pydantic's traceback, exit 1."""
    from cellguard.control.settings import build_guard
    from cellguard.errors import ConfigError, ScenarioError
    from cellguard.scenario import parse_scenario

    origin = f"{path}: the record's guard settings, refused by this cellguard (replay cannot build the guard that ran)"
    try:
        build_guard(cell, parse_scenario({"cell": rc.cell, "guard": rc.guard}, origin=origin).guard)
    except ScenarioError as exc:
        raise CalibrationError(str(exc)) from None
    except ConfigError as exc:
        raise CalibrationError(f"{origin}: {exc}") from None


def _chunk(recorded):
    from cellguard.policy.chunk import ActionChunk

    return ActionChunk(actions=recorded.actions, t_obs_ns=recorded.t_obs_ns, dt_ns=recorded.dt_ns,
                       uncertainty=recorded.uncertainty)


def _apply(cell, terms: JointTerms, vary: Vary | None, factor: float) -> None:
    m, joints = cell.model, hinge_joints(cell)
    dadr = cell.drives.dadr[joints]
    values = {"friction": terms.friction.copy(), "damping": terms.damping.copy(), "armature": terms.armature.copy()}
    if vary is not None:
        values[vary.parameter][[cell.profile.joint_names[i] for i in joints].index(vary.joint)] *= factor
    m.dof_frictionloss[dadr], m.dof_damping[dadr], m.dof_armature[dadr] = (values["friction"], values["damping"],
                                                                            values["armature"])
    cell.drives.nominal_frictionloss[joints] = values["friction"]
    cell.drives.nominal_damping[joints] = values["damping"]
    if terms.payload_kg:
        m.body_mass[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "tool")] += terms.payload_kg


def mismatch(rc: RecordedCycle, sim: Trajectory, joints: list[int]) -> dict:
    """Per hinge joint: RMS current error [A] over the recorded current's spread, RMS position error [rad]."""
    cur = np.sqrt(np.mean((sim.current[:, joints] - rc.ticks.current[:, joints]) ** 2, axis=0))
    spread = np.maximum(np.std(rc.ticks.current[:, joints], axis=0), 1e-9)
    pos = np.sqrt(np.mean((sim.q[:, joints] - rc.ticks.q[:, joints]) ** 2, axis=0))
    cmd = np.abs(sim.q_cmd[:, joints] - rc.ticks.q_cmd[:, joints]).max(axis=0)
    return {"joints": [rc.joints[j] for j in joints], "current_nrmse": (cur / spread).tolist(),
            "position_rms": pos.tolist(), "setpoint_max_gap": cmd.tolist(),
            "cost": float(np.mean(cur / spread))}


@dataclass(frozen=True)
class UsedProfile:
    """The profile whose measured terms the replay put in (none for the nominal model), beside the record's: a
    replay months later says which model it ran, and ``note`` says so when that is not the record's."""

    version: str | None = None
    sha256: str | None = None
    calibration: str | None = None  # its calibration version; None: typed-in values (or the nominal model)
    path: str | None = None  # the file read, or DOCUMENT; None: the cell's own profile
    recorded: str | None = None  # the sha256 of the profile the record was made with, as its context says
    note: str | None = None  # the record's profile and this one, when they differ

    @property
    def is_records(self) -> bool:
        return self.sha256 is not None and self.sha256 == self.recorded

    def describe(self) -> str:
        """``profile VERSION (calibration C, sha256 S) from FILE``, or ``the cell's own profile ...``."""
        named = _named(self.version, self.calibration, self.sha256)
        return f"the cell's own {named}" if self.path is None else f"{named} from {self.path}"

    def model(self, model: str) -> str:
        """The model replayed in, in words: which profile, and whether it is the record's."""
        if model == "nominal":
            return "nominal model (the MJCF's terms, no profile's)"
        whose = ("the record names no profile" if self.recorded is None else
                 "the record's" if self.is_records else "not the record's")
        return f"calibrated model of {self.describe()}, {whose}"

    @classmethod
    def of(cls, profile, path: str | None, recorded: str | None) -> UsedProfile:
        """``profile`` read from ``path`` (a file, ``DOCUMENT``, or None for the cell's own)."""
        return cls(profile.version, profile.sha256, profile.calibration.version if profile.calibration else None,
                   path, recorded)

    def to_dict(self) -> dict:
        return {"profile_version": self.version, "profile_sha256": self.sha256, "calibration": self.calibration,
                "profile": self.path, "record_profile_sha256": self.recorded, "profile_note": self.note}


def model_terms(rc: RecordedCycle, cell, model: str, profile: Path | None) -> tuple[JointTerms, UsedProfile]:
    """The terms to replay ``rc`` with and which profile they are: ``profile`` (``--profile``), else the record's
    own (the file its run read, or the copy a later ``identify --write`` kept beside it; gone, the document the
    record holds), else (an older record) the cell's own, with a note whenever that is not the profile the record
    was made with or its calibration's payload could not be had."""
    from cellguard.embodiment import load_profile

    recorded = rc.profile.get("sha256")
    if model == "nominal":
        return JointTerms.nominal(cell), UsedProfile(recorded=recorded)
    looked: list[Path] = []
    if profile is None:
        profile, looked = _record_profile(rc, cell)
        if profile is not None:  # the record's own file: its payload as the document's, a missing MJCF noted
            found = load_profile(cell.model, profile, cell.profile.robot)
            payload, note = _payload([profile], found, cell, "the record's profile file was found")
            return JointTerms.of_profile(cell, found, payload), replace(UsedProfile.of(found, str(profile), recorded),
                                                                       note=note)
        document = _record_document(rc, cell)
        if document is not None:
            payload, note = _payload(_places(rc), document, cell, "the record's profile file was not found; its own "
                                     "document gave the measured terms")
            return (JointTerms.of_profile(cell, document, payload),
                    replace(UsedProfile.of(document, DOCUMENT, recorded), note=note))
    terms = JointTerms.from_profile(cell, profile)
    prof = cell.profile if profile is None else load_profile(cell.model, profile, cell.profile.robot)
    used = UsedProfile.of(prof, None if profile is None else str(profile), recorded)
    if used.is_records or not recorded:
        return terms, used
    calibration = (rc.profile.get("calibration") or {}).get("version")
    where = f", not found at {' or '.join(map(str, looked))} (name it with --profile)" if looked else ""
    note = (f"the record was made with {_named(rc.profile.get('version'), calibration, recorded)}{where}; "
            f"replaying with {used.describe()}")
    return terms, replace(used, note=note)


def _record_profile(rc: RecordedCycle, cell) -> tuple[Path | None, list[Path]]:
    """The profile file the record was made with, found by its sha256 where its run read it or, recalibrated
    since, as the kept ``NAME.VERSION.yaml`` beside it; None when it is the cell's own or not found (with the
    paths looked at)."""
    recorded = rc.profile.get("sha256")
    if not recorded or recorded == cell.profile.sha256:
        return None, []
    version = rc.profile.get("version")
    looked = [path for place in _places(rc)
              for path in (place, kept_copy(place, version))]
    for path in looked:
        if _sha256(path) == recorded:
            return path, []
    return None, looked


def _places(rc: RecordedCycle) -> list[Path]:
    """Where the record's run read its profile, resolved (the old copy is beside a link's target), once each: the
    file the context names (absolute), then the scenario's path as typed (relative to the working folder: an older
    record's only clue, and a site folder moved or copied whole). Each is taken only if its sha256 is the record's.
    A NUL in a path from the record names no file."""
    named = [p for p in (rc.profile.get("file"), rc.calibration_file) if isinstance(p, str) and "\0" not in p]
    return list(dict.fromkeys(Path(os.path.realpath(p)) for p in named))


def _record_document(rc: RecordedCycle, cell):
    """The profile the record was made with as replay reads it, from the document its context holds (``embodiment
    show --json``: each measured value in the unit it names): its version, sha256, calibration and measured
    friction, damping and armature, on the cell's joints. None when that is the cell's own profile, or the record
    is older than the document; CalibrationError when the document is not one."""
    from cellguard.embodiment import Calibration, MeasuredParameter
    from cellguard.units import parse_quantity

    doc, recorded = rc.profile.get("profile"), rc.profile.get("sha256")
    if doc is None or not recorded or recorded == cell.profile.sha256:
        return None
    try:
        if doc["sha256"] != recorded:
            raise ValueError(f"its sha256 {doc['sha256']} is not the record's {recorded}")
        if doc["robot"] != cell.profile.robot:  # its terms would name joints the model lacks: dropped unseen
            raise ValueError(f"it is a profile of robot {doc['robot']!r}; the {cell.name} model is of "
                             f"{cell.profile.robot!r}")
        strange = sorted({m["joint"] for m in doc["measured"]} - set(cell.profile.joint_names) - {None})
        if strange:
            raise ValueError(f"it measured joints the {cell.name} model lacks: {', '.join(map(str, strange))}")
        measured = tuple(MeasuredParameter(**m | {"value": parse_quantity(f"{m['value']} {m['unit']}",
                                                                            f"measured[{i}].value", _TERMS)})
                         for i, m in enumerate(doc["measured"]) if m["parameter"] in VARIED)
        cal = doc["calibration"]
        if cal is not None and (not cal["mjcf"] or Path(cal["mjcf"]).name != cal["mjcf"]):
            raise ValueError(f"calibration.mjcf {cal['mjcf']!r} is not a file name")
        calibration = None if cal is None else Calibration(**cal | {"records": tuple(cal["records"])})
        return replace(cell.profile, version=str(doc["version"]), sha256=recorded, measured=measured,
                       calibration=calibration)
    except (KeyError, TypeError, AttributeError, ValueError) as exc:
        raise CalibrationError(f"the record's profile document (context embodiment.profile) cannot be read: "
                               f"{exc}; name the profile with --profile") from None


def _payload(places: list[Path], prof, cell, why: str) -> tuple[float, str | None]:
    """The payload [kg] ``prof``'s calibration (of ``cell``'s robot) put into its calibrated MJCF (a profile and its
    document keep none: the MJCF stores it), read beside the first of ``places`` that has it; 0 and a note saying so
    (``why`` the note begins) when none has."""
    from cellguard.calibrate.mjcf import calibrated_payload

    if prof.calibration is None:
        return 0.0, None
    refused = []
    for place in places:
        try:
            return calibrated_payload(place, prof, cell.model, "the record's profile"), None
        except CalibrationError as exc:  # a file read and refused (a payload over the bound) says why in the note
            if place.with_name(prof.calibration.mjcf).is_file():
                refused.append(str(exc))
    mjcf = " or ".join(str(p.with_name(prof.calibration.mjcf)) for p in places) or prof.calibration.mjcf
    return 0.0, (f"{why}, but the calibrated MJCF that holds the payload cannot be read at {mjcf}"
                 + (f" ({'; '.join(refused)})" if refused else "") + ": replayed without a payload (name the profile "
                 "with --profile)")


def _sha256(path: Path) -> str | None:
    """The sha256 of the file at ``path``; None when there is none to read."""
    from cellguard.errors import ProfileError
    from cellguard.yaml_file import read_bounded

    try:
        return hashlib.sha256(read_bounded(path, "profile", ProfileError)).hexdigest()
    except (ProfileError, ValueError):  # ValueError: a NUL in a path from the record
        return None


def _named(version, calibration, sha256) -> str:
    return f"profile {version} (calibration {calibration or 'none'}, sha256 {str(sha256)[:12]})"


@dataclass(frozen=True)
class ReplayResult:
    rc: RecordedCycle
    model: str  # calibrated | nominal
    simulated: Trajectory
    mismatch: dict
    vary: Vary | None = None
    best: float | None = None  # the factor that best reproduces the cycle
    search: tuple[tuple[float, float], ...] = ()  # (factor, cost) in the order tried
    profile: UsedProfile = UsedProfile()

    def to_dict(self) -> dict:
        out = {"cell": self.rc.cell, "cycle": self.rc.cycle, "model": self.model, "ticks": int(len(self.rc.t_ns)),
               "joints": list(self.rc.joints), **self.profile.to_dict(), "mismatch": self.mismatch}
        if self.vary is not None:
            out["vary"] = {"parameter": self.vary.parameter, "joint": self.vary.joint,
                           "range": [self.vary.low, self.vary.high], "best_factor": self.best,
                           "tried": [list(p) for p in self.search]}
        return out


def replay(path: Path, cycle: int, model: str = "calibrated", profile: Path | None = None,
           vary: str | None = None) -> ReplayResult:
    """Replay cycle ``cycle`` of the record in ``path``; with ``vary`` search the factor that best reproduces it."""
    from cellguard.robot.registry import make_cell

    if model not in ("calibrated", "nominal"):
        raise CalibrationError(f"--model: {model!r} is not one of calibrated, nominal")
    rc = load_cycle(path, cycle)
    cell = make_cell(rc.cell, seed=rc.seed)
    if tuple(cell.profile.joint_names) != rc.joints:
        raise CalibrationError(f"{path}: joints {list(rc.joints)}; the {rc.cell} model has "
                               f"{list(cell.profile.joint_names)}")
    _check_guard(rc, cell, path)
    terms, used = model_terms(rc, cell, model, profile)
    joints = hinge_joints(cell)
    v = parse_vary(vary, cell) if vary is not None else None
    if v is None:
        sim = simulate(rc, terms)
        return ReplayResult(rc, model, sim, mismatch(rc, sim, joints), profile=used)
    tried: dict[float, float] = {}

    def cost(factor: float) -> float:
        tried[factor] = mismatch(rc, simulate(rc, terms, v, factor), joints)["cost"]
        return tried[factor]

    grid = np.linspace(v.low, v.high, GRID)
    best = grid[int(np.argmin([cost(f) for f in grid]))]
    step = grid[1] - grid[0]
    lo, hi = max(v.low, best - step), min(v.high, best + step)
    found = minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": XTOL})
    factor = float(found.x) if found.fun <= tried[best] else float(best)
    sim = simulate(rc, terms, v, factor)
    return ReplayResult(rc, model, sim, mismatch(rc, sim, joints), v, factor, tuple(tried.items()), used)
