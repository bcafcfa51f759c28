"""What every learned-policy adapter shares: the action map in, a chunk in robot joints out.

An adapter (ONNX, openpi, LeRobot) is a small ``Backend``: it turns ``PolicyInputs`` (the
state in the policy's own order and units, time since reset, camera measurements, the task)
into raw actions (H, A). ``MappedPolicy`` wraps it into the ``Policy`` protocol: it builds the
inputs through the ``ActionMap``, maps the raw actions onto this robot's joints, stamps the
chunk with the observation time and keeps the latency of every call. Its ``map_document`` is the
map in force, resolved, for the record's context: the model's hash alone reads the same under a
map in rad and one in deg.
"""

from __future__ import annotations

import copy
import hashlib
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np

from cellguard.errors import CellguardError, ConfigError
from cellguard.embodiment.action_map import ActionMap, load_action_map, parse_action_map
from cellguard.embodiment.profile import SOFT_MARGIN
from cellguard.options import bounded_float
from cellguard.options import split_options as _split
from cellguard.policy.chunk import ActionChunk
from cellguard.robot.state import Observation
from cellguard.yaml_file import parse_yaml


class InferenceError(CellguardError):
    """A policy call that failed at run time: a timeout, a lost server, a malformed reply."""


class StepPeriodUnstated(ConfigError):
    """A policy source that states no step period and was given no ``?dt=`` (a frozen release says what to do)."""


@dataclass(frozen=True)
class PolicyInputs:
    """What a backend sees: ``state`` (A,) in the policy's units, measurements by name, SI."""

    state: np.ndarray
    time_s: float  # since the last reset (the start of the episode)
    measurements: dict[str, np.ndarray] = field(default_factory=dict)
    task: str = ""


class Backend(Protocol):
    """A model that answers ``PolicyInputs`` with raw actions (H, A) in its own space."""

    action_dim: int
    action_names: tuple[str, ...] | None  # as the model names them, when it does
    embedded_map: str | None  # an action map shipped with the model (YAML text), if any
    dt_s: float | None  # the step period [s] the model or server states, if it does

    def infer(self, inputs: PolicyInputs) -> np.ndarray: ...

    def reset(self) -> None: ...

    def content_hash(self) -> str: ...


def split_options(arg: str, allowed: dict[str, str], scheme: str) -> tuple[str, dict[str, str]]:
    """A policy source's ``TARGET?k=v`` (``options.split_options``), its errors named ``policy: SCHEME``."""
    return _split(arg, allowed, f"policy: {scheme}", f"{scheme}:TARGET")


DT_RANGE_S = (0.001, 1.0)  # a chunk's step period [s]: from a 1 kHz servo step to 1 s
TIMEOUT_RANGE_S = (0.01, 60.0)  # a receive timeout [s]


def option_float(options: dict[str, str], key: str, default: float, scheme: str,
                 limits: tuple[float, float]) -> float:
    """The option ``key`` (e.g. ``dt=0.02``) within ``limits``, else ``default``; a bad value names the option."""
    return bounded_float(options.get(key, default), f"policy: {scheme}: option {key}", *limits)


def stated_dt(metadata: dict, key: str, where: str) -> float | None:
    """The step period a model's or server's ``metadata`` states under ``key``, checked; None when it states none."""
    return bounded_float(metadata[key], f"{where} {key}", *DT_RANGE_S) if key in metadata else None


def step_period(backend: Backend, options: dict[str, str], source: str) -> float:
    """The chunk's step period [s]: ``?dt=``, else the one the model or server states. Neither is refused: the
    20 ms once assumed played a policy of 100 ms steps five times too fast, and nothing said so."""
    if "dt" not in options and backend.dt_s is None:
        raise StepPeriodUnstated(f"policy: {source}: the step period is not stated: give ?dt=SECONDS (the policy's control "
                          f"period, e.g. 0.0667 for 15 Hz)")
    return option_float(options, "dt", backend.dt_s, source.partition(":")[0], DT_RANGE_S)


def resolve_map(backend: Backend, cell, map_path: str | None, source: str) -> ActionMap:
    """The action map for ``backend`` on ``cell``: a file, else the model's own, else by joint name. Unnamed
    actions with no map are refused: taken as the joints in order, in SI, a policy in degrees ran as radians."""
    profile = cell.profile
    names = backend.action_names
    if map_path:
        amap = load_action_map(Path(map_path), profile)
    elif backend.embedded_map:
        amap = parse_action_map(parse_yaml(backend.embedded_map, f"{source} (embedded map)"), profile,
                                origin=f"{source} (embedded map)")
    else:
        if not names:
            raise ConfigError(f"policy: {source} names none of its {backend.action_dim} actions and carries no "
                              f"action map: give one, ?map=FILE (which joint each action drives, in which unit)")
        if len(names) != backend.action_dim:  # read as names not of the robot's joints: give a map, it said
            raise ConfigError(f"policy: {source} names {len(names)} actions but outputs {backend.action_dim} per "
                              f"step; its action names and its output must agree")
        joints = tuple(n.removesuffix(".pos") for n in names)
        if sorted(joints) != sorted(profile.joint_names) or backend.action_dim != profile.dof:
            raise ConfigError(f"policy: {source} outputs {backend.action_dim} actions ({', '.join(names)}), which "
                              f"are not the joints of {profile.robot!r}; give an action map: ?map=FILE")
        order = {j: i for i, j in enumerate(joints)}
        entries = [{"name": names[order[j.name]], "joint": j.name, "unit": "rad" if j.kind == "hinge" else "m"}
                   for j in profile.joints]
        entries.sort(key=lambda e: order[e["joint"]])
        amap = parse_action_map({"robot": profile.robot, "actions": entries}, profile, origin=source)
    amap.check_policy(backend.action_dim, backend.action_names, source)
    return amap


def map_document(amap: ActionMap, joint_names: tuple[str, ...]) -> dict:
    """``amap`` as resolved, in the policy's action order, and its sha256, to record with the run: two maps that
    drive the robot differently (a unit, a sign, an offset) differ here, two spellings of one do not. A joint
    [rad or m] = offset + sign * si_per_unit * action; an ee target [m or rad] = sign * si_per_unit * action.
    ``resolved_sha256`` hashes this document, not the map's file."""
    actions: list[dict] = [{}] * amap.action_dim
    for a in amap.joint_actions:
        actions[a.column] = {"name": a.name, "joint": joint_names[a.joint], "sign": 1 if a.factor > 0 else -1,
                             "si_per_unit": abs(a.factor), "offset": a.offset}
    for e in amap.ee_actions:
        actions[e.column] = {"name": e.name, "ee": e.axis, "sign": 1 if e.factor > 0 else -1,
                             "si_per_unit": abs(e.factor)}
    ik = amap.ik
    doc = {
        "robot": amap.robot,
        "actions": actions,
        "hold": {joint_names[j]: value for j, value in sorted(amap.held)},
        "ik": None if ik is None else {"site": ik.site, "joints": list(ik.joints), "mode": ik.mode,
                                       "orientation_cost": ik.orientation_cost, "axes": list(ik.axes)},
    }
    text = json.dumps(doc, sort_keys=True, separators=(",", ":"), ensure_ascii=False)
    return {**doc, "resolved_sha256": hashlib.sha256(text.encode()).hexdigest()}


class MappedPolicy:
    """A backend behind the ``Policy`` protocol, mapped onto ``cell`` by ``action_map`` (its IK inside the soft limits
    of the guard's ``soft_margin``)."""

    def __init__(self, backend: Backend, action_map: ActionMap, cell, source: str, dt_s: float, task: str = "",
                 soft_margin: float = SOFT_MARGIN):
        self.backend, self.action_map, self.source, self.task = backend, action_map, source, task
        self.dt_ns = round(dt_s * 1e9)
        self.map_document = map_document(action_map, cell.profile.joint_names)
        self.solver = None
        if action_map.ik is not None:
            from cellguard.policy.ik import IkSolver

            self.solver = IkSolver(copy.deepcopy(cell.model), cell.profile, action_map.ik, soft_margin)
        self.latencies_ns: list[int] = []
        self._t0_ns: int | None = None

    def reset(self) -> None:
        self._t0_ns = None
        self.backend.reset()

    def content_hash(self) -> str:
        return self.backend.content_hash()

    def close(self) -> None:
        """Release what the backend holds (a connection); the policy is not used afterwards."""
        close = getattr(self.backend, "close", None)
        if close is not None:
            close()

    def infer(self, observation: Observation) -> ActionChunk:
        start = time.perf_counter_ns()
        if self._t0_ns is None:
            self._t0_ns = observation.t_ns
        inputs = PolicyInputs(
            state=self.action_map.to_policy_state(observation.q, self.solver),
            time_s=(observation.t_ns - self._t0_ns) * 1e-9,
            measurements=observation.measurements,
            task=self.task,
        )
        raw = np.asarray(self.backend.infer(inputs), dtype=np.float64)
        if raw.ndim == 1:
            raw = raw[None, :]
        if raw.ndim != 2 or raw.shape[1] != self.action_map.action_dim:
            raise InferenceError(f"policy: {self.source} returned actions of shape {raw.shape}, expected "
                              f"(H, {self.action_map.action_dim})")
        actions = self.action_map.to_robot(raw, observation.q, self.solver)
        self.latencies_ns.append(time.perf_counter_ns() - start)
        return ActionChunk(actions=actions, t_obs_ns=observation.t_ns, dt_ns=self.dt_ns)
