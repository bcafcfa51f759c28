"""ActionMap: a policy's action space onto this robot's joints, declared in YAML, checked at load.

A policy trained on another robot names its actions in its own order and units. The map says,
per action, which joint it drives and how (``robot = offset + sign * factor * value``), which
joints the policy does not drive (held at a fixed value), and which actions are end-effector
targets solved by differential IK (``cellguard.policy.ik``). The same map turns this robot's
joint state into the policy's state vector, so the policy sees what it was trained on.

```yaml
robot: arm-pick-place
actions:                       # the policy's action vector, in its order
  - {name: elbow.pos, joint: elbow, unit: deg, sign: -1, offset: "0.1 rad"}
  - {name: gripper, joint: gripper, unit: "1", scale: "23 mm", offset: "6 mm"}
  - {name: ee.x, ee: x, unit: mm}
hold: {wrist_roll: "0 rad"}
ik: {site: tcp, joints: [shoulder_pan, shoulder_lift, elbow, wrist_flex], mode: absolute}
```
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cellguard.embodiment import Profile
from cellguard.embodiment.profile import JointLimits, text_field
from cellguard.errors import ConfigError
from cellguard.units import parse_quantity
from cellguard.yaml_file import read_yaml, reject_unknown_keys

_JOINT_DIM = {"hinge": ("angle",), "slide": ("length",)}
_DIMENSIONLESS = {"1": 1.0, "%": 0.01}
FACTOR_RANGE = (1e-9, 1e3)  # |SI per policy unit|: from 1 nm (or nrad) to 1 km per unit
EE_AXES = ("x", "y", "z", "roll", "pitch", "yaw")
_TOP_KEYS = {"robot", "actions", "hold", "ik"}
_ACTION_KEYS = {"name", "joint", "ee", "unit", "sign", "offset", "scale"}


@dataclass(frozen=True)
class JointAction:
    """One policy action driving one joint: ``robot = offset + factor * value`` (factor carries the sign)."""

    name: str
    column: int  # position in the policy's action vector
    joint: int  # position in the profile's joint order
    factor: float  # SI per policy unit, signed
    offset: float  # [rad] or [m]


@dataclass(frozen=True)
class EeAction:
    """One component of an end-effector target, in SI after ``factor``: [m] or [rad]."""

    name: str
    column: int
    axis: str  # one of EE_AXES
    factor: float


@dataclass(frozen=True)
class IkSpec:
    """Which site the end-effector actions place, with which joints, absolute or as deltas."""

    site: str
    joints: tuple[str, ...]
    mode: str  # "absolute" or "delta"
    orientation_cost: float
    axes: tuple[str, ...]  # the EE_AXES the policy sets; the others hold the pose at the chunk's start

    @property
    def full_orientation(self) -> bool:
        """Whether the policy sets yaw (else only the tool axis direction is held)."""
        return "yaw" in self.axes


@dataclass(frozen=True)
class ActionMap:
    """Policy action vector (A,) <-> robot joint vector (dof,), checked against a profile."""

    robot: str
    names: tuple[str, ...]
    joint_actions: tuple[JointAction, ...]
    ee_actions: tuple[EeAction, ...]
    held: tuple[tuple[int, float], ...]  # (joint index, value [rad] or [m])
    ik: IkSpec | None

    @property
    def action_dim(self) -> int:
        return len(self.names)

    def check_policy(self, action_dim: int, names: tuple[str, ...] | None, source: str) -> None:
        """Refuse a policy whose action size or names differ from the map; the message names both."""
        if action_dim != self.action_dim:
            raise ConfigError(f"action map: {source} outputs {action_dim} actions per step, the map declares "
                              f"{self.action_dim} ({', '.join(self.names)})")
        if names is not None and len(names) != action_dim:  # compared pairwise, the extra or missing names went unseen
            raise ConfigError(f"action map: {source} names {len(names)} actions but outputs "
                              f"{action_dim} per step, and the map declares {self.action_dim}")
        if names is not None and tuple(names) != self.names:
            for i, (theirs, ours) in enumerate(zip(names, self.names)):
                if theirs != ours:
                    raise ConfigError(f"action map: actions[{i}].name is {ours!r} but {source} calls action {i} "
                                      f"{theirs!r}")

    def to_robot(self, actions: np.ndarray, q_now: np.ndarray, solver=None) -> np.ndarray:
        """Policy actions (H, A) -> joint targets (H, dof); ``solver`` (an ``IkSolver``) for EE actions."""
        actions = np.asarray(actions, dtype=np.float64)
        out = np.repeat(np.asarray(q_now, dtype=np.float64)[None, :], actions.shape[0], axis=0)
        for a in self.joint_actions:
            out[:, a.joint] = a.offset + a.factor * actions[:, a.column]
        for joint, value in self.held:
            out[:, joint] = value
        if self.ee_actions:
            # Unmapped axes are known from ik.axes, not marked NaN: a NaN here is the policy's, and stays one.
            targets = np.zeros((actions.shape[0], len(EE_AXES)))
            for a in self.ee_actions:
                targets[:, EE_AXES.index(a.axis)] = a.factor * actions[:, a.column]
            out[:, solver.joint_index] = solver.solve(targets, q_now, delta=self.ik.mode == "delta")
        return out

    def to_policy_state(self, q: np.ndarray, solver=None) -> np.ndarray:
        """This robot's joint state (dof,) -> the policy's state vector (A,) in its units and order."""
        state = np.zeros(self.action_dim)
        for a in self.joint_actions:
            state[a.column] = (q[a.joint] - a.offset) / a.factor
        if self.ee_actions:
            pose = solver.pose(q)
            for a in self.ee_actions:
                state[a.column] = pose[EE_AXES.index(a.axis)] / a.factor
        return state


def identity_map(profile: Profile, names: tuple[str, ...] | None = None) -> ActionMap:
    """The map of a policy trained on this very robot: one action per joint, SI, profile order."""
    names = tuple(names) if names is not None else profile.joint_names
    actions = [{"name": n, "joint": j.name, "unit": "rad" if j.kind == "hinge" else "m"}
               for n, j in zip(names, profile.joints)]
    return parse_action_map({"robot": profile.robot, "actions": actions}, profile)


def load_action_map(path: Path, profile: Profile) -> ActionMap:
    """Read an action map file and check it against ``profile``."""
    raw = read_yaml(path, "action map")
    return parse_action_map(raw, profile, origin=str(path))


def parse_action_map(raw: object, profile: Profile, origin: str = "action map") -> ActionMap:
    """Validate a decoded action map against ``profile``; raise ConfigError naming the field. Its ``robot:`` is the
    profile's robot, which is not always the name of the cell a scenario names (cell so101-pick-place, robot
    so101): the refusal says which to write (the cell's name was called the map's, the robot's the cell's)."""
    if not isinstance(raw, dict):
        raise ConfigError(f"{origin}: expected a mapping with keys {', '.join(sorted(_TOP_KEYS))}")
    reject_unknown_keys(raw, sorted(_TOP_KEYS), f"{origin}: ")
    robot = raw.get("robot")
    if robot != profile.robot:
        raise ConfigError(f"{origin}: robot: the map is for {robot!r}; this cell's robot (its profile) is "
                          f"{profile.robot!r}: write robot: {profile.robot}")
    entries = raw.get("actions")
    if not isinstance(entries, list) or not entries:
        raise ConfigError(f"{origin}: actions: expected a non-empty list, one entry per policy action")
    kinds = {j.name: j.kind for j in profile.joints}
    names: list[str] = []
    joint_actions: list[JointAction] = []
    ee_actions: list[EeAction] = []
    driven: dict[str, str] = {}
    for i, entry in enumerate(entries):
        field = f"{origin}: actions[{i}]"
        if not isinstance(entry, dict):
            raise ConfigError(f"{field}: expected a mapping with name, joint or ee, unit")
        reject_unknown_keys(entry, sorted(_ACTION_KEYS), f"{field}.")
        name = entry.get("name")
        if not isinstance(name, str) or not name:
            raise ConfigError(f"{field}.name: expected the policy's name for this action")
        text_field(name, f"{field}.name", ConfigError)
        if name in names:
            raise ConfigError(f"{field}.name: {name!r} appears twice")
        names.append(name)
        if ("joint" in entry) == ("ee" in entry):
            raise ConfigError(f"{field}: give exactly one of joint (a robot joint) or ee (one of {', '.join(EE_AXES)})")
        sign = entry.get("sign", 1)
        if isinstance(sign, bool) or sign not in (1, -1):
            raise ConfigError(f"{field}.sign: expected 1 or -1, got {sign!r}")
        if "ee" in entry:
            axis = entry["ee"]
            if not isinstance(axis, str) or axis not in EE_AXES:
                raise ConfigError(f"{field}.ee: {axis!r} is not an end-effector axis; axes: {', '.join(EE_AXES)}")
            dims = ("length",) if axis in ("x", "y", "z") else ("angle",)
            factor = sign * _unit_factor(entry, dims, f"{field}")
            if "offset" in entry:
                raise ConfigError(f"{field}.offset: end-effector targets take no offset")
            if any(a.axis == axis for a in ee_actions):
                raise ConfigError(f"{field}.ee: axis {axis!r} is mapped twice")
            ee_actions.append(EeAction(name, i, axis, factor))
            continue
        joint = entry["joint"]
        if not isinstance(joint, str) or joint not in kinds:
            raise ConfigError(f"{field}.joint: {joint!r} is not a joint of {profile.robot!r}; "
                              f"joints: {', '.join(profile.joint_names)}")
        if joint in driven:
            raise ConfigError(f"{field}.joint: {joint!r} is already driven by action {driven[joint]!r}")
        driven[joint] = name
        dims = _JOINT_DIM[kinds[joint]]
        factor = sign * _unit_factor(entry, dims, field, joint=joint)
        offset = parse_quantity(entry["offset"], f"{field}.offset", dims) if "offset" in entry else 0.0
        _check_offset(offset, entry.get("offset"), profile.joints[profile.index(joint)], f"{field}.offset")
        joint_actions.append(JointAction(name, i, profile.index(joint), factor, offset))
    held = _held(raw.get("hold") or {}, profile, kinds, driven, origin)
    ik = _ik(raw.get("ik"), profile, driven, held, ee_actions, origin)
    covered = set(driven) | {profile.joint_names[j] for j, _ in held} | set(ik.joints if ik else ())
    for joint in profile.joint_names:
        if joint not in covered:
            raise ConfigError(f"{origin}: joint {joint!r} is not mapped: drive it from an action, "
                              f"give it a value under hold, or list it under ik.joints")
    return ActionMap(profile.robot, tuple(names), tuple(joint_actions), tuple(ee_actions), held, ik)


def _unit_factor(entry: dict, dims: tuple[str, ...], field: str, joint: str | None = None) -> float:
    """SI per policy unit from ``unit`` and ``scale``; its size must lie in FACTOR_RANGE (never zero: the
    state sent to the policy divides by it)."""
    factor = _raw_factor(entry, dims, field, joint)
    lo, hi = FACTOR_RANGE
    if not lo <= abs(factor) <= hi:
        raise ConfigError(f"{field}.scale: unit {entry.get('unit')!r} with scale {entry.get('scale', 1)!r} gives "
                          f"{factor:g} SI per policy unit; its size must lie in [{lo:g}, {hi:g}]")
    return factor


def _check_offset(offset: float, text: object, limits: JointLimits, field: str) -> None:
    """Refuse an offset (the joint's position where the policy outputs 0) further outside the joint's limits
    than its whole range, or a full turn for a hinge: a wrong unit (``1000 m``) that otherwise refused every
    chunk at run time."""
    lo, hi = limits.position
    reach = max(hi - lo, 2.0 * np.pi) if limits.kind == "hinge" else hi - lo
    if not lo - reach <= offset <= hi + reach:
        unit = "rad" if limits.kind == "hinge" else "m"
        raise ConfigError(f"{field}: {text} puts {limits.name} at {offset:.4g} {unit} where the policy outputs 0, "
                          f"more than {reach:.4g} {unit} outside its limits [{lo:g}, {hi:g}] {unit}; check the unit")


def _raw_factor(entry: dict, dims: tuple[str, ...], field: str, joint: str | None) -> float:
    unit = entry.get("unit")
    what = f"joint {joint!r}" if joint else "this axis"
    if unit is None:
        raise ConfigError(f"{field}.unit: missing; the unit the policy's value is in")
    if str(unit) in _DIMENSIONLESS:
        if "scale" not in entry:
            raise ConfigError(f"{field}.scale: a dimensionless action (unit {unit!r}) needs a scale with a unit, "
                              f"e.g. '23 mm', for {what}")
        return _DIMENSIONLESS[str(unit)] * parse_quantity(entry["scale"], f"{field}.scale", dims)
    try:
        factor = parse_quantity(f"1 {unit}", f"{field}.unit", dims)
    except ConfigError as exc:
        raise ConfigError(f"{exc} (for {what}; or '1' / '%' with a scale)") from None
    scale = entry.get("scale", 1.0)
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not np.isfinite(scale) or scale == 0:
        raise ConfigError(f"{field}.scale: with unit {unit!r} the scale is a non-zero number, got {scale!r}")
    return factor * float(scale)


def _held(raw: object, profile: Profile, kinds: dict, driven: dict, origin: str) -> tuple[tuple[int, float], ...]:
    if not isinstance(raw, dict):
        raise ConfigError(f"{origin}: hold: expected a mapping of joint to value, e.g. {{wrist_roll: '0 rad'}}")
    held = []
    for joint, value in raw.items():
        if not isinstance(joint, str) or joint not in kinds:
            raise ConfigError(f"{origin}: hold.{joint}: not a joint of {profile.robot!r}; "
                              f"joints: {', '.join(profile.joint_names)}")
        if joint in driven:
            raise ConfigError(f"{origin}: hold.{joint}: already driven by action {driven[joint]!r}")
        si = parse_quantity(value, f"{origin}: hold.{joint}", _JOINT_DIM[kinds[joint]])
        lo, hi = profile.joints[profile.index(joint)].position
        if not lo <= si <= hi:
            raise ConfigError(f"{origin}: hold.{joint}: {value} lies outside the position limits [{lo:g}, {hi:g}]")
        held.append((profile.index(joint), si))
    return tuple(held)


def _ik(raw: object, profile: Profile, driven: dict, held: tuple, ee: list, origin: str) -> IkSpec | None:
    needed = bool(ee)
    if raw is None:
        if needed:
            raise ConfigError(f"{origin}: ik: end-effector actions need an ik section (site, joints)")
        return None
    if not needed:
        raise ConfigError(f"{origin}: ik: given, but no action is an end-effector target (ee)")
    allowed = {"site", "joints", "mode", "orientation_cost"}
    if not isinstance(raw, dict) or any(k not in allowed for k in raw):
        raise ConfigError(f"{origin}: ik: expected a mapping with keys {', '.join(sorted(allowed))}")
    site, joints = raw.get("site"), raw.get("joints")
    if not isinstance(site, str):
        raise ConfigError(f"{origin}: ik.site: expected the name of a site of the model, e.g. tcp")
    if not isinstance(joints, list) or not joints:
        raise ConfigError(f"{origin}: ik.joints: expected the list of joints the IK moves")
    held_names = {profile.joint_names[j] for j, _ in held}
    for k, joint in enumerate(joints):
        if not isinstance(joint, str) or joint not in profile.joint_names:
            raise ConfigError(f"{origin}: ik.joints: {joint!r} is not a joint of {profile.robot!r}; "
                              f"joints: {', '.join(profile.joint_names)}")
        if joint in joints[:k]:
            raise ConfigError(f"{origin}: ik.joints[{k}]: {joint!r} is listed twice")
        if joint in driven or joint in held_names:
            raise ConfigError(f"{origin}: ik.joints: {joint!r} is also driven or held; a joint has one source")
    mode = raw.get("mode", "absolute")
    if mode not in ("absolute", "delta"):
        raise ConfigError(f"{origin}: ik.mode: expected absolute or delta, got {mode!r}")
    cost = raw.get("orientation_cost", 1.0)
    if isinstance(cost, bool) or not isinstance(cost, (int, float)) or not 0.0 <= cost <= 10.0:
        raise ConfigError(f"{origin}: ik.orientation_cost: expected a number in [0, 10], got {cost!r}")
    return IkSpec(site, tuple(joints), mode, float(cost), tuple(a.axis for a in ee))
