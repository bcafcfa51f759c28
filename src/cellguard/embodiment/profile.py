"""The embodiment profile: what this robot may do, and what was measured on it.

A profile is a YAML file next to the robot's MJCF. Loading checks it against the model: a
joint the model does not have, a limit outside the model's range or beyond what any robot has
(``_PLAUSIBLE``, ``POSITION_MAX``), or a number without its unit is refused with an error that names
the field. So is a measured parameter cellguard does not know (``Friction`` was taken with any unit
and sign), and a measured value that cannot be one of
its parameter (friction, damping, armature, actuator_time_constant, backlash): in another dimension
(friction is a torque on a hinge, a force on a slide; armature an inertia or a mass), below zero,
or beyond its range (friction above the joint's effort); a second entry for the same joint and
parameter (one of them would silently win); a date that is not an ISO date (YYYY-MM-DD), never compared
with today (``iso_date``); a symmetry pair of a joint with itself, of two joints of different kinds,
named twice, or whose mirror lies outside the other joint's range; text with control characters; and a
version that cannot name a file (``identify --write`` keeps ``NAME.VERSION.yaml`` beside the profile).
"""

from __future__ import annotations

import datetime
import hashlib
import os
import re
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from cellguard.errors import ConfigError, ProfileError
from cellguard.units import parse_quantity
from cellguard.yaml_file import parse_yaml, read_bounded, reject_unknown_keys

_LINEAR = {"position": ("length",), "velocity": ("length/s",), "acceleration": ("length/s^2",),
           "jerk": ("length/s^3",), "effort": ("force",), "torque_constant": ("force/A",)}
_ANGULAR = {"position": ("angle",), "velocity": ("angle/s",), "acceleration": ("angle/s^2",),
            "jerk": ("angle/s^3",), "effort": ("torque",), "torque_constant": ("torque/A",)}
# the SI unit each limit is held (and shown) in
SI_UNITS = {"hinge": {"position": "rad", "velocity": "rad/s", "acceleration": "rad/s^2", "jerk": "rad/s^3",
                      "effort": "N*m", "torque_constant": "N*m/A"},
            "slide": {"position": "m", "velocity": "m/s", "acceleration": "m/s^2", "jerk": "m/s^3", "effort": "N",
                      "torque_constant": "N/A"}}
# the plausible range of each limit, SI, a hinge's or a slide's: the fastest joints turn at tens of rad/s (linear
# motors a few m/s), reach 1e4 rad/s^2 and 1e7 rad/s^3, the strongest hold 1e5 N*m, a geared drive gives at most
# some 1e3 N*m/A; a limit orders of magnitude beyond, or under 1e-6 (a joint that cannot move), is a typing or unit
# error that turns the guard off (1e308 let a 2 rad step through in one tick, or overflowed at the guard's start)
_PLAUSIBLE = {"velocity": (1e-6, 1e3), "acceleration": (1e-6, 1e6), "jerk": (1e-6, 1e9), "effort": (1e-6, 1e7),
              "torque_constant": (1e-6, 1e6)}
# the farthest a position limit may lie from zero, SI: some 1600 turns of a hinge, 10 km of a slide. The model bounds
# a limited joint; one it leaves unlimited took +-1e308 rad, whose range overflowed to inf and made the guard's soft
# limits [inf, -inf] (every tick tracker_failed)
POSITION_MAX = 1e4
SOFT_MARGIN = 0.02  # the guard's soft limits by default: this fraction of each joint's range inside its limits
_PARAMETER_DIMENSIONS = ("torque", "force", "time", "angle", "length", "mass", "inertia", "damping")
# the dimension of a measured parameter on a hinge or a slide joint (None: no unit cellguard reads yet); each is
# at least zero. A parameter not listed is refused: a misspelt one would be taken with any unit and sign.
_MEASURED = {
    "friction": {"hinge": ("torque",), "slide": ("force",)},  # dry friction, at most the joint's effort
    "damping": {"hinge": ("damping",), "slide": None},
    "armature": {"hinge": ("inertia",), "slide": ("mass",)},
    "actuator_time_constant": {"hinge": ("time",), "slide": ("time",)},
    "backlash": {"hinge": ("angle",), "slide": ("length",)},
}
# the largest value a known parameter may have, SI, beyond which it is a typing error, not a robot
# (friction is bounded by the joint's effort instead: friction above it would hold the joint still)
MEASURED_MAX = {"damping": 1e4, "armature": 1e3, "actuator_time_constant": 10.0, "backlash": 1.0}
_SI = {"torque": "N*m", "force": "N", "damping": "N*m*s/rad", "inertia": "kg*m^2", "mass": "kg", "time": "s",
       "angle": "rad", "length": "m"}


@dataclass(frozen=True)
class JointLimits:
    """Limits of one joint, SI: [rad] or [m], per second, per s^2, per s^3; effort [N·m] or [N]."""

    name: str
    kind: str  # "hinge" or "slide"
    position: tuple[float, float]
    velocity: float
    acceleration: float
    jerk: float
    effort: float
    torque_constant: float  # [N·m/A] or [N/A] at the joint: current = effort / torque_constant


@dataclass(frozen=True)
class MeasuredParameter:
    """A value measured on this robot, with when and how, so a later reading can be compared."""

    joint: str
    parameter: str
    value: float  # SI
    unit: str  # as written in the profile
    measured: str  # ISO date, YYYY-MM-DD
    method: str

    @property
    def value_as_written(self) -> float:
        """The value in ``unit`` (12.0 for 12 ms), rounded to 12 digits so the division's last bit is not shown."""
        return float(f"{self.value / parse_quantity(f'1 {self.unit}', 'unit', _PARAMETER_DIMENSIONS):.12g}")

    @property
    def as_written(self) -> str:
        """The value in the unit the profile wrote it in, e.g. ``0.05 deg``."""
        return f"{self.value_as_written:.6g} {self.unit}"


@dataclass(frozen=True)
class SymmetryPair:
    """``right`` mirrors ``left``: q_right = sign * q_left in a mirrored motion."""

    left: str
    right: str
    sign: float


@dataclass(frozen=True)
class Calibration:
    """Which identification the measured values come from (``identify --write``): its version id, the
    calibrated MJCF written beside the profile, when, from which records, and the version it replaced."""

    version: str
    mjcf: str  # file name beside the profile
    date: str  # ISO date, YYYY-MM-DD
    records: tuple[str, ...]
    previous: str  # the profile version before this calibration

    def to_dict(self) -> dict:
        return {"version": self.version, "mjcf": self.mjcf, "date": self.date, "records": list(self.records),
                "previous": self.previous}


@dataclass(frozen=True)
class Profile:
    """A robot's embodiment. The arrays are per joint in ``joint_names`` order, read-only."""

    robot: str
    version: str
    joints: tuple[JointLimits, ...]
    measured: tuple[MeasuredParameter, ...]
    symmetry: tuple[SymmetryPair, ...]
    sha256: str
    calibration: Calibration | None = None  # None: the measured values were typed in, not identified

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def dof(self) -> int:
        return len(self.joints)

    def index(self, joint: str) -> int:
        """Position of ``joint`` in the arrays; an unknown name lists the joints."""
        try:
            return self.joint_names.index(joint)
        except ValueError:
            raise ProfileError(f"unknown joint {joint!r}; joints: {', '.join(self.joint_names)}") from None

    def array(self, attr: str) -> np.ndarray:
        """A read-only float64 array of one limit over all joints, e.g. ``array('velocity')``."""
        values = np.array([getattr(j, attr) for j in self.joints], dtype=np.float64)
        values.setflags(write=False)
        return values

    @property
    def q_min(self) -> np.ndarray:
        return self.array_pos(0)

    @property
    def q_max(self) -> np.ndarray:
        return self.array_pos(1)

    def soft_limits(self, margin: float = SOFT_MARGIN) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper soft limits (D,), ``margin`` of each joint's range inside its position limits: where the
        guard brakes (``GuardConfig.soft_margin``), and so where the IK keeps its solutions."""
        lo, hi = self.q_min, self.q_max
        inside = margin * (hi - lo)
        return lo + inside, hi - inside

    def first_outside(self, q, slack: float = 0.0) -> int | None:
        """The first joint pose ``q`` puts outside its position limits, widened by ``slack`` of its range; None."""
        lo, hi = self.q_min, self.q_max
        margin = slack * (hi - lo)
        out = np.flatnonzero((np.asarray(q) < lo - margin) | (np.asarray(q) > hi + margin))
        return int(out[0]) if out.size else None

    def array_pos(self, side: int) -> np.ndarray:
        values = np.array([j.position[side] for j in self.joints], dtype=np.float64)
        values.setflags(write=False)
        return values

    def to_dict(self) -> dict:
        return {
            "robot": self.robot,
            "version": self.version,
            "sha256": self.sha256,
            "joints": [j.__dict__ | {"position": list(j.position)} for j in self.joints],
            # in the unit each names (the value is SI inside): 0.012 labelled ms was really 12 ms
            "measured": [m.__dict__ | {"value": m.value_as_written} for m in self.measured],
            "symmetry": [s.__dict__ for s in self.symmetry],
            "calibration": self.calibration.to_dict() if self.calibration else None,
        }


class OtherRobot(ProfileError):
    """A profile of another robot than the one it was given for (``parse_profile``'s ``robot``)."""


def load_profile(model: mujoco.MjModel, path: Path, robot: str | None = None) -> Profile:
    """Read ``path`` and check it against ``model`` (and, given, the ``robot`` it must be of: checked first); raise
    ProfileError naming the bad field."""
    return parse_profile(model, read_bounded(path, "profile", ProfileError), str(path), robot)


def kept_copy(path: Path, version: str) -> Path:
    """Where ``identify --write``, rewriting the profile at ``path``, keeps it as it was at ``version``:
    ``NAME.VERSION.yaml`` beside it (beside a link's target: the target is what is rewritten). A release and a
    replay bound to that version find it there."""
    path = Path(path)
    target = Path(os.path.realpath(path)) if path.is_symlink() else path
    return target.with_name(f"{target.stem}.{version}{target.suffix}")


def calibrated_profile(model: mujoco.MjModel, current: Profile, path: Path) -> Profile:
    """The profile at ``path`` (one ``identify --write`` wrote) in place of ``current``: it must be of the same
    robot with the same joints, order, limits and symmetry; only what was measured (and the calibration) may differ.
    The refusal names the first difference (it said "other joints or limits", for joints in another order too)."""
    try:
        new = load_profile(model, Path(path), current.robot)
    except ProfileError as exc:
        raise ProfileError(f"calibration: {exc}") from None
    why = mismatch(new, current)
    if why is not None:
        raise ProfileError(f"calibration: {path} {why}; a calibration changes only measured values")
    return new


def mismatch(new: Profile, current: Profile, exact: bool = True) -> str | None:
    """The first way ``new`` differs from ``current`` in what the cell is built on, or None: the robot, the joints,
    the symmetry pairs, and when ``exact`` the joints' order (every action and array follows it) and limits. Not
    exact, it is what ``embodiment show`` asks: a profile of this robot, whatever its order and limits."""
    theirs = f"{current.robot}'s profile (version {current.version})"
    if new.robot != current.robot:
        return f"is a profile of robot {new.robot!r}; the robot is {current.robot!r}"
    if set(new.joint_names) != set(current.joint_names):
        missing = [j for j in current.joint_names if j not in new.joint_names]
        extra = [j for j in new.joint_names if j not in current.joint_names]
        what = "; ".join(f"{', '.join(js)} {word}" for js, word in ((extra, "extra"), (missing, "missing")) if js)
        return f"has joints {list(new.joint_names)}; {theirs} has {list(current.joint_names)} ({what})"
    if exact and new.joint_names != current.joint_names:
        return (f"has the same joints in another order ({', '.join(new.joint_names)}; {theirs}: "
                f"{', '.join(current.joint_names)}); actions and limits follow the profile's order")
    for ours, its in zip(new.joints, current.joints) if exact else ():
        key = next((k for k in SI_UNITS[its.kind] if getattr(ours, k) != getattr(its, k)), None)
        if key is not None:
            unit = SI_UNITS[its.kind][key]
            return (f"has joints.{its.name}.{key} {_si(getattr(ours, key), unit)} where {theirs} has "
                    f"{_si(getattr(its, key), unit)}")
    if set(new.symmetry) != set(current.symmetry):
        ours = [_pair(s) for s in new.symmetry if s not in current.symmetry] or ["no other pair"]
        its = [_pair(s) for s in current.symmetry if s not in new.symmetry] or ["no other pair"]
        return f"has symmetry {', '.join(ours)} where {theirs} has {', '.join(its)}"
    return None


def _si(value: float | tuple[float, float], unit: str) -> str:
    """A limit as held, every digit (2.9999999 rad/s shown as 3 would hide the difference)."""
    return f"[{value[0]!r}, {value[1]!r}] {unit}" if isinstance(value, tuple) else f"{value!r} {unit}"


def parse_profile(model: mujoco.MjModel, raw_bytes: bytes, path: str = "profile", robot: str | None = None) -> Profile:
    """Check the YAML text ``raw_bytes`` (from ``path``) against ``model``; its sha256 is the profile's.
    A ProfileError names ``path`` and the field: a profile may come from a file the user named. Given the ``robot``
    it must be of, a profile of another is refused as such first: the arm's on the SO-101, whose joints share its
    names, was refused for a joint's range, not for being another robot's."""
    raw = parse_yaml(raw_bytes, path, ProfileError)
    named = raw.get("robot") if isinstance(raw, dict) else None
    if robot is not None and isinstance(named, str) and named != robot:
        raise OtherRobot(f"{path}: is a profile of robot {named!r}; the robot is {robot!r}")
    try:
        return _profile(model, raw, hashlib.sha256(raw_bytes).hexdigest())
    except ProfileError as exc:
        raise ProfileError(f"{path}: {exc}") from None


def _profile(model: mujoco.MjModel, raw: object, sha256: str) -> Profile:
    if not isinstance(raw, dict):
        raise ProfileError("expected a mapping at the top level")
    allowed = {"robot", "model", "version", "joints", "measured", "symmetry", "calibration"}
    reject_unknown_keys(raw, sorted(allowed), "", ProfileError)
    for key in ("robot", "version", "joints"):
        if key not in raw:
            raise ProfileError(f"{key}: missing")
    if not isinstance(raw["joints"], dict) or not raw["joints"]:
        raise ProfileError("joints: expected a mapping of joint name to limits")
    joints = tuple(_joint(model, name, spec) for name, spec in raw["joints"].items())
    by_name = {j.name: j for j in joints}
    measured = tuple(_measured(i, m, by_name) for i, m in enumerate(_list(raw, "measured")))
    first: dict[tuple[str, str], int] = {}
    for i, m in enumerate(measured):
        j = first.setdefault((m.joint, m.parameter), i)
        if j != i:
            raise ProfileError(f"measured[{i}]: {m.parameter} of {m.joint} is already measured[{j}]; keep one entry "
                               "per joint and parameter (the one to use)")
    symmetry = tuple(_symmetry(i, s, by_name) for i, s in enumerate(_list(raw, "symmetry")))
    paired: dict[str, int] = {}  # a joint in two pairs made the mirror map no permutation, and no check saw it
    for i, pair in enumerate(symmetry):
        for side, joint in (("left", pair.left), ("right", pair.right)):
            j = paired.setdefault(joint, i)
            if j != i:
                raise ProfileError(f"symmetry[{i}].{side}: {joint} is already paired in symmetry[{j}]; a joint "
                                   "mirrors one joint")
    if "model" in raw:
        text_field(raw["model"], "model")
    return Profile(
        robot=text_field(raw["robot"], "robot"),
        version=_version(raw["version"], "version"),
        joints=joints,
        measured=measured,
        symmetry=symmetry,
        sha256=sha256,
        calibration=_calibration(raw["calibration"]) if raw.get("calibration") is not None else None,
    )


def _list(raw: dict, key: str) -> list:
    """The list at ``key``; left out or written empty (``symmetry:``) is none. ``false``, ``0``, ``""`` or ``{}``
    are mistakes, not "none" (they were taken as empty)."""
    value = raw.get(key)
    if value is None:
        return []
    if not isinstance(value, list):
        raise ProfileError(f"{key}: expected a list, got {type(value).__name__}")
    return value


def text_field(value: object, field: str, error: type[ConfigError] = ProfileError) -> str:
    """A text field: a string (the YAML loader reads ``measured: 2026-10-14`` as one); anything else is a
    mistake that ``str()`` would hide (``robot: [1]`` named the robot "[1]"). Action maps use it too."""
    if isinstance(value, str):
        if not value.isprintable():  # an escape code recolours the terminal that prints it; a NUL ends a file name
            raise error(f"{field}: {value!r} holds control characters")
        return value
    raise error(f"{field}: expected text, got {type(value).__name__}")


def iso_date(value: object, field: str) -> str:
    """A day as ``YYYY-MM-DD`` that exists (``2026-13-45`` and ``yesterday`` are none). Not compared with today's
    clock: a profile loads the same on any host at any time (one dated while the clock ran fast stopped the cell
    once NTP set it right, and a host whose clock reset to 1970 could load none); ``identify`` refuses a date
    after tomorrow where it makes one (``calibrate.identify.refuse_ahead``)."""
    text = text_field(value, field)
    try:
        day = datetime.date.fromisoformat(text) if re.fullmatch(r"[0-9]{4}-[0-9]{2}-[0-9]{2}", text) else None
    except ValueError:
        day = None
    if day is None:
        raise ProfileError(f"{field}: {text!r} is not a date; write YYYY-MM-DD, e.g. \"2026-10-14\"")
    return text


def _version(value: object, field: str) -> str:
    """A version id: text that can stand in a file name (``identify --write`` keeps NAME.VERSION.yaml beside the
    profile), so no path separator and not blank."""
    text = text_field(value, field)
    if not text.strip() or "/" in text or "\\" in text or text in (".", ".."):
        raise ProfileError(f"{field}: {text!r} cannot name a file (it names the copies kept beside the profile); "
                           "write it without / or \\")
    return text


def _is_joint(value: object, names: set[str]) -> bool:
    return isinstance(value, str) and value in names


def _quantity(text: object, field: str, dimensions: tuple[str, ...]) -> float:
    try:
        return parse_quantity(text, field, dimensions)
    except ConfigError as exc:
        raise ProfileError(str(exc)) from None


def _joint(model: mujoco.MjModel, name: object, spec: object) -> JointLimits:
    jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name) if isinstance(name, str) else -1
    if jid < 0:
        known = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, i) for i in range(model.njnt)]
        raise ProfileError(f"joints.{name}: unknown joint; the model has: {', '.join(k for k in known if k)}")
    jtype = model.jnt_type[jid]
    if jtype == mujoco.mjtJoint.mjJNT_HINGE:
        kind, dims = "hinge", _ANGULAR
    elif jtype == mujoco.mjtJoint.mjJNT_SLIDE:
        kind, dims = "slide", _LINEAR
    else:
        raise ProfileError(f"joints.{name}: only hinge and slide joints can be profiled")
    if not isinstance(spec, dict):
        raise ProfileError(f"joints.{name}: expected a mapping of limits")
    reject_unknown_keys(spec, dims, f"joints.{name}.", ProfileError)
    for key in dims:
        if key not in spec:
            raise ProfileError(f"joints.{name}.{key}: missing")
    pos = spec["position"]
    if not isinstance(pos, list) or len(pos) != 2:
        raise ProfileError(f"joints.{name}.position: expected [min, max] with units")
    lo = _quantity(pos[0], f"joints.{name}.position[0]", dims["position"])
    hi = _quantity(pos[1], f"joints.{name}.position[1]", dims["position"])
    if not lo < hi:
        raise ProfileError(f"joints.{name}.position: min {lo:g} must be below max {hi:g}")
    if not -POSITION_MAX <= lo < hi <= POSITION_MAX:
        raise ProfileError(f"joints.{name}.position: [{pos[0]}, {pos[1]}] reaches beyond the plausible "
                           f"+-{POSITION_MAX:g} {SI_UNITS[kind]['position']}; no joint travels that far: give the "
                           "range it has, in its unit")
    if model.jnt_limited[jid]:
        mlo, mhi = model.jnt_range[jid]
        if lo < mlo - 1e-9 or hi > mhi + 1e-9:
            raise ProfileError(
                f"joints.{name}.position: [{lo:g}, {hi:g}] lies outside the model's range [{mlo:g}, {mhi:g}]"
            )
    values = {}
    for key in ("velocity", "acceleration", "jerk", "effort", "torque_constant"):
        values[key] = _quantity(spec[key], f"joints.{name}.{key}", dims[key])
        if values[key] <= 0:
            raise ProfileError(f"joints.{name}.{key}: must be positive, got {values[key]:g}")
        low, high = _PLAUSIBLE[key]
        if not low <= values[key] <= high:
            raise ProfileError(f"joints.{name}.{key}: {spec[key]} is outside the plausible {low:g}..{high:g} "
                               f"{SI_UNITS[kind][key]}; no robot has it: check the value and its unit")
    return JointLimits(name=name, kind=kind, position=(lo, hi), **values)


def _measured(i: int, spec: object, joints: dict[str, JointLimits]) -> MeasuredParameter:
    field = f"measured[{i}]"
    keys = ("joint", "parameter", "value", "measured", "method")
    if not isinstance(spec, dict):
        raise ProfileError(f"{field}: expected a mapping with {', '.join(keys)}")
    reject_unknown_keys(spec, keys, f"{field}.", ProfileError)
    for key in keys:
        if key not in spec:
            raise ProfileError(f"{field}.{key}: missing")
    if not _is_joint(spec["joint"], set(joints)):
        raise ProfileError(f"{field}.joint: {spec['joint']!r} is not a profiled joint")
    joint = joints[spec["joint"]]
    parameter = text_field(spec["parameter"], f"{field}.parameter")
    if parameter not in _MEASURED:
        raise ProfileError(f"{field}.parameter: {parameter!r} is not a parameter cellguard knows; known: "
                           f"{', '.join(_MEASURED)}")
    return MeasuredParameter(
        joint=joint.name,
        parameter=parameter,
        value=_measured_value(spec["value"], f"{field}.value", parameter, joint),
        unit=str(spec["value"]).split()[1],
        measured=iso_date(spec["measured"], f"{field}.measured"),
        method=text_field(spec["method"], f"{field}.method"),
    )


def _measured_value(text: object, field: str, parameter: str, joint: JointLimits) -> float:
    """The SI value of a measured ``parameter`` of ``joint``: in the parameter's dimension, at least zero and
    within its range (friction at most the joint's effort)."""
    dims = _MEASURED[parameter][joint.kind]
    if dims is None:
        raise ProfileError(f"{field}: {parameter} of a {joint.kind} joint ({joint.name}) has no unit cellguard "
                           "reads yet; leave it out")
    value = _quantity(text, field, dims)
    if value < 0.0:
        raise ProfileError(f"{field}: {parameter} of {joint.name} must be at least zero, got {text}")
    limit = joint.effort if parameter == "friction" else MEASURED_MAX[parameter]
    if value > limit:
        what = "the joint's effort " if parameter == "friction" else "the most it can be, "
        raise ProfileError(f"{field}: {parameter} of {joint.name} {text} is above {what}{limit:g} {_SI[dims[0]]}; "
                           "check the value and its unit")
    return value


def _symmetry(i: int, spec: object, joints: dict[str, JointLimits]) -> SymmetryPair:
    """One mirrored pair: two joints of the same kind (a hinge mirrors a hinge), not a joint with itself."""
    field = f"symmetry[{i}]"
    if not isinstance(spec, dict) or set(spec) != {"left", "right", "sign"}:
        raise ProfileError(f"{field}: expected {{left, right, sign}}")
    for side in ("left", "right"):
        if not _is_joint(spec[side], set(joints)):
            raise ProfileError(f"{field}.{side}: {spec[side]!r} is not a profiled joint")
    left, right = joints[spec["left"]], joints[spec["right"]]
    if left.name == right.name:
        raise ProfileError(f"{field}: {left.name} cannot mirror itself; pair it with the other side's joint")
    if left.kind != right.kind:
        raise ProfileError(f"{field}: {left.name} is a {left.kind} and {right.name} a {right.kind}; a joint mirrors "
                           "one of its own kind")
    if isinstance(spec["sign"], bool) or spec["sign"] not in (1, -1):
        raise ProfileError(f"{field}.sign: must be 1 or -1, got {spec['sign']!r}")
    pair = SymmetryPair(left=spec["left"], right=spec["right"], sign=float(spec["sign"]))
    lo, hi = sorted(pair.sign * q for q in left.position)  # where the mirror puts the right joint
    if max(lo, right.position[0]) >= min(hi, right.position[1]):  # a mirrored motion was refused chunk by chunk
        raise ProfileError(f"{field}: {_pair(pair)} puts {right.name} in [{lo:g}, {hi:g}], outside its range "
                           f"[{right.position[0]:g}, {right.position[1]:g}] for every position of {left.name}; "
                           "check the sign")
    return pair


def _pair(pair: SymmetryPair) -> str:
    return f"{pair.right} = {pair.sign:+g} * {pair.left}"


def _calibration(spec: object) -> Calibration:
    keys = ("version", "mjcf", "date", "records", "previous")
    if not isinstance(spec, dict):
        raise ProfileError(f"calibration: expected a mapping with {', '.join(keys)}")
    reject_unknown_keys(spec, keys, "calibration.", ProfileError)
    for key in keys:
        if key not in spec:
            raise ProfileError(f"calibration.{key}: missing")
    records = spec["records"]
    if not isinstance(records, list) or not all(isinstance(r, str) for r in records):
        raise ProfileError("calibration.records: expected a list of record ids")
    for k, record in enumerate(records):
        text_field(record, f"calibration.records[{k}]")
    version, previous = (_version(spec[k], f"calibration.{k}") for k in ("version", "previous"))
    mjcf, date = text_field(spec["mjcf"], "calibration.mjcf"), iso_date(spec["date"], "calibration.date")
    if Path(mjcf).name != mjcf:
        raise ProfileError(f"calibration.mjcf: {mjcf!r} must be a file name beside the profile, not a path")
    return Calibration(version, mjcf, date, tuple(records), previous)
