"""Scenario files: which cell, which policy, how many cycles, which faults to inject.

Validated before anything runs: an unknown key, a wrong type or an impossible value raises
ScenarioError naming the key (``faults[1].dx_mm: ...``).

A file a scenario names (``calibration``, the policy's file and its ``?map=``, a bridge's ``?units=``) is one rule,
for every reader: relative to the scenario file's real location (a linked scenario's target's folder), normalised to
the real file (``..`` and links resolved; an absolute path resolved alike), so the run, its messages and its record
name the file that is read (``beside``).
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from urllib.parse import quote, urlencode

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, ValidationError, model_validator

from cellguard.control.config import GuardConfig
from cellguard.errors import CellguardError, ScenarioError
from cellguard.options import parse_query
from cellguard.robot.faults import FAULTS, AnyFault
from cellguard.robot.process import PROCESS_CHANGES, AnyProcessChange, declared_changes
from cellguard.robot.recovery import RECOVERIES, RecoveryPolicy
from cellguard.robot.world_changes import first_refused
from cellguard.yaml_file import read_yaml, yaml_bool_text


class CycleSettings(BaseModel):
    """Where a cycle ends. ``task``: the simulated cell's own task (the default on a cell);
    ``input``: a digital input of the robot turns true (a PLC's part-done signal); ``home``: the
    robot left its home pose and came back within ``tolerance``; ``policy``: the policy says its
    episode is over; ``time``: a fixed episode length."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    source: Literal["task", "input", "home", "policy", "time"] = "task"
    input: str = Field(default="cycle_done", min_length=1, description="digital input name (source: input)")
    tolerance: float = Field(default=0.01, gt=0.0, le=0.1, description="home pose tolerance per joint [rad] or [m] "
                             "(a cycle has left home 5 tolerances away)")
    seconds: float = Field(default=10.0, gt=0.0, le=3600.0, description="episode length (source: time) [s]")

    @model_validator(mode="after")
    def _only_its_own_settings(self):
        """A setting of another source is a mistake (``source: task, seconds: 5`` ran with no time limit)."""
        owner = {"input": "input", "tolerance": "home", "seconds": "time"}
        stray = sorted(k for k in self.model_fields_set if owner.get(k, self.source) != self.source)
        if stray:
            raise ValueError(f"{', '.join(stray)} belongs to another source than {self.source!r} "
                             f"({', '.join(f'{k}: {owner[k]}' for k in stray)})")
        return self


STALE_FLOOR_S = 0.02  # the default staleness limit at least: at 1 kHz 2.5 periods would be a scheduler's hiccup [s]
STALE_PERIODS = 2.5  # the default staleness limit in servo periods: one lost packet (two periods) and some jitter
STALE_MIN_PERIODS = 2  # a staleness limit or streaming read timeout under this many periods is refused


class RealtimeSettings(BaseModel):
    """The wall-clock loop: inference worker, overrun budget, and the robot link's watchdogs."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    inference: Literal["thread", "process"] = "thread"
    overrun_budget: int = Field(default=50, ge=0, le=1_000_000,
                                description="ticks later than one period allowed before a stop")
    stale_s: float | None = Field(default=None, gt=0.0, le=5.0, description="robot state older than this is stale "
                                  "[s]; unset: the longer of 20 ms and 2.5 servo periods of the robot")
    read_timeout_s: float = Field(default=0.05, gt=0.0, le=5.0, description="a read waits at most this long [s]")
    drop_budget: int = Field(default=100, ge=0, le=1_000_000, description="lost robot packets allowed before a stop")
    stop_category: Literal[0, 1, 2] = Field(default=1, description="stop category of a robot link fault")

    def for_robot(self, period_ns: int, streams: bool) -> RealtimeSettings:
        """These settings on a robot of servo period ``period_ns``, with the staleness limit in force (what the
        record states). On a robot that ``streams`` its states, one lost packet leaves the newest state two periods
        old, so a staleness limit or read timeout (the silence since its last packet) under two periods stopped a
        50 Hz robot at its first lost packet (the 20 ms default, one period there) and is refused. A robot read on
        each tick (a LeRobot bridge, a simulated cell) stamps its state at the read: no limit of its is refused."""
        default_s = max(STALE_FLOOR_S, STALE_PERIODS * period_ns * 1e-9)
        limits = {"stale_s": self.stale_s, "read_timeout_s": self.read_timeout_s} if streams else {}
        for key, value in limits.items():
            if value is not None and round(value * 1e9) < STALE_MIN_PERIODS * period_ns:
                unset = f", or leave it unset ({default_s:g} s on this robot)" if key == "stale_s" else ""
                raise ScenarioError(f"realtime.{key}: {value * 1e3:g} ms is under two servo periods of the robot "
                                    f"({STALE_MIN_PERIODS * period_ns * 1e-6:g} ms at {1e9 / period_ns:.4g} Hz): one "
                                    f"lost packet would stop it; give at least "
                                    f"{STALE_MIN_PERIODS * period_ns * 1e-9:g} s{unset}")
        return self.model_copy(update={"stale_s": default_s if self.stale_s is None else self.stale_s})


class Scenario(BaseModel):
    """A run of a simulated cell: an acceptance phase, then production with injected faults."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    cell: str
    seed: int = Field(default=0, ge=0)
    policy: str = "scripted"
    policy_hz: float = Field(default=20.0, ge=10.0, le=50.0, description="inference cadence [Hz]")
    acceptance_cycles: int = Field(default=20, ge=0, le=100_000)
    production_cycles: int = Field(default=60, ge=0, le=1_000_000)
    site: str = "sim-site"
    cell_id: str = "cell-1"
    faults: list[AnyFault] = Field(default_factory=list, max_length=10_000)
    process_changes: list[AnyProcessChange] = Field(default_factory=list, max_length=10_000)
    guard: GuardConfig = Field(default_factory=GuardConfig)
    robot: str = Field(default="sim", min_length=1, description="sim, or a bridge: SCHEME:ARGUMENT")
    cycle: CycleSettings = Field(default_factory=CycleSettings)
    realtime: RealtimeSettings = Field(default_factory=RealtimeSettings)
    recovery: RecoveryPolicy | None = None
    calibration: Path | None = Field(default=None, description="a profile written by `identify --write`: the robot "
                                     "runs with its measured values, and every record names its calibration version")
    residual_monitor: bool = Field(default=False, description="watch each cycle's measured torque against the "
                                   "model's (the calibration's, else the profile's measured values): the point where "
                                   "the robot has drifted beyond its simulator, in the record and the diagnosis")
    _path: str | None = PrivateAttr(default=None)  # the file ``load_scenario`` read it from

    @property
    def total_cycles(self) -> int:
        return self.acceptance_cycles + self.production_cycles

    def declared_process(self, cycle: int) -> list[dict]:
        """The process changes declared by ``cycle`` (what the record's context says; undeclared ones stay out)."""
        return declared_changes(self.process_changes, cycle)

    def check_against(self, cell) -> None:
        """Refuse faults the cell cannot simulate, joints its profile does not have and recoveries it cannot run;
        naming the scenario's file, as a refusal while it is read does (without, the user had a key and no file)."""
        try:
            self._check_cell(cell)
        except ScenarioError as exc:
            if self._path is None:
                raise
            raise ScenarioError(f"{self._path}: {exc}") from None

    def _check_cell(self, cell) -> None:
        for i, fault in enumerate(self.faults):
            if fault.kind not in cell.supported_faults:
                raise ScenarioError(
                    f"faults[{i}].kind: {fault.kind!r} cannot be simulated in cell {cell.name!r}; "
                    f"it supports: {', '.join(sorted(cell.supported_faults))}"
                )
            if fault.kind == "late_recovery" and self.recovery is None:
                raise ScenarioError(f"faults[{i}].kind: 'late_recovery' slows recoveries and the scenario has no "
                                    f"recovery: section, so it would never act")
            for joint in fault.joints():
                if joint not in cell.profile.joint_names:
                    raise ScenarioError(
                        f"faults[{i}].joint: {joint!r} is not a joint of {cell.name!r}; "
                        f"joints: {', '.join(cell.profile.joint_names)}"
                    )
        for i, change in enumerate(self.process_changes):
            if not hasattr(cell, change.hook):
                raise ScenarioError(f"process_changes[{i}].kind: {change.kind!r} cannot be simulated in cell "
                                    f"{cell.name!r}")
        refused = first_refused(cell, self.process_changes)
        if refused is not None:
            i, why = refused
            raise ScenarioError(f"process_changes[{i}]: from cycle {self.process_changes[i].at_cycle}, with every "
                                f"change in force then, {why}")
        if self.recovery is not None:
            self.recovery.check_against(cell)


def parse_scenario(raw: object, origin: str = "scenario") -> Scenario:
    """Validate a decoded YAML document; raise ScenarioError naming the first bad key.

    Validation is pydantic's strict mode on the document as JSON: a string or a boolean is never
    taken for a number (``acceptance_cycles: "1"``, ``seed: true``), while YAML lists still fill
    tuples; every number must be finite (``.inf``, ``.nan`` are refused wherever they appear) and
    no text may hold control characters.
    """
    if not isinstance(raw, dict):
        raise ScenarioError(f"{origin}: expected a mapping of keys, got {type(raw).__name__}")
    _check_values(raw, (), origin)
    try:
        document = json.dumps(raw, default=str)  # YAML dates and timestamps become the strings they were
    except (TypeError, ValueError) as exc:
        raise ScenarioError(f"{origin}: cannot be read as a scenario ({exc})") from None
    try:
        scenario = Scenario.model_validate_json(document, strict=True)
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = _format_loc(err["loc"])
        msg = err["msg"]
        if err["type"] == "extra_forbidden":
            msg = "unknown key"
        elif err["type"] == "union_tag_invalid":
            known = ("fault kind" if loc.startswith("faults") else "recovery" if loc.startswith("recovery")
                     else "process change kind")
            msg = f"unknown {known}; known: {err['ctx']['expected_tags']}"
        elif err["type"].endswith("_type") or err["type"].endswith("_parsing"):
            msg = f"{msg}, got {err['input']!r}"
            if err["type"] == "bool_type" and yaml_bool_text(err["input"]):
                msg += ": text to YAML 1.2; write true or false, unquoted"
        raise ScenarioError(f"{origin}: {loc}: {msg}") from None
    _check_cycles(scenario, origin)
    _check_bridge(scenario, origin)
    return scenario


def _check_bridge(scenario: Scenario, origin: str) -> None:
    """Refuse faults and process changes on a robot behind a bridge: it would never see them, and the record would
    list them as what happened; and recoveries: a bridge reports no failed check to start one (refused by what the
    robot lacks as the run started, a sim-server read "cannot run on 'arm-pick-place' ... (pick-place cells can)",
    after the bridge had connected). Here, not as the run starts: a release plan's check refuses the stage before
    its first run (a later run refused after the earlier ones had run)."""
    if scenario.robot == "sim":
        return
    for key in ("faults", "process_changes"):
        if getattr(scenario, key):
            raise ScenarioError(f"{origin}: {key}: applied to simulated cells only; robot {scenario.robot!r} is a "
                                "bridge")
    if scenario.recovery:
        raise ScenarioError(f"{origin}: recovery: runs on simulated cells only (a bridge reports no failed check to "
                            f"start one); robot {scenario.robot!r} is a bridge")


def _check_cycles(scenario: Scenario, origin: str) -> None:
    """Refuse a run of no cycles (nothing to run, nothing to retreat from) and a fault or process change
    set for a cycle the run never reaches (it would never happen, and say nothing)."""
    total = scenario.total_cycles
    if total == 0:
        raise ScenarioError(f"{origin}: acceptance_cycles, production_cycles: both 0; a run needs at least one cycle")
    for key in ("faults", "process_changes"):
        for i, item in enumerate(getattr(scenario, key)):
            field = "at_cycle" if hasattr(item, "at_cycle") else "from_cycle"
            cycle = getattr(item, field)
            if cycle >= total:
                raise ScenarioError(f"{origin}: {key}[{i}].{field}: {item.kind} at cycle {cycle} would never happen; "
                                    f"the run's cycles (acceptance_cycles + production_cycles = {total}) are "
                                    f"numbered 0 to {total - 1}")


def _check_values(value: object, loc: tuple, origin: str) -> None:
    """Refuse NaN and infinities, text with control characters (a ``site:`` that recolours a terminal), sets and
    bytes."""
    if isinstance(value, (set, bytes)):  # YAML's !!set and !!binary: their text would be recorded as the value
        raise ScenarioError(f"{origin}: {_format_loc(loc)}: a YAML {'!!set' if isinstance(value, set) else '!!binary'} "
                            "is no scenario value")
    if isinstance(value, float) and not math.isfinite(value):
        raise ScenarioError(f"{origin}: {_format_loc(loc)}: {value} is not a finite number")
    if isinstance(value, str) and not value.isprintable():
        raise ScenarioError(f"{origin}: {_format_loc(loc)}: {value!r} holds control characters")
    if isinstance(value, dict):
        for key, item in value.items():
            _check_values(key, loc, origin)
            _check_values(item, (*loc, str(key)), origin)
    elif isinstance(value, list):
        for i, item in enumerate(value):
            _check_values(item, (*loc, i), origin)


def load_scenario(path: Path) -> Scenario:
    """Read and validate a scenario file; a file it names by a relative path is beside it (``files_beside``)."""
    scenario = parse_scenario(read_yaml(path, "scenario", ScenarioError), origin=str(path))
    try:
        scenario = files_beside(scenario, scenario_folder(path))
    except ScenarioError as exc:
        raise ScenarioError(f"{path}: {exc}") from None
    scenario._path = str(path)
    return scenario


def scenario_folder(path: Path) -> Path:
    """The folder the files a scenario file names are taken from: the real folder of the file, a link's target's (the
    folder beside a link, while ``identify --write`` and ``replay`` took the target's, gave them other files)."""
    return Path(os.path.realpath(path)).parent


def beside(folder: Path, name: str | Path, key: str) -> Path:
    """The real file ``name`` (a scenario's ``key``) names from ``folder``: relative to it, ``..`` and links resolved,
    so what runs, its messages and its record name the file read (``cal/../../run1/x`` named a path that was none of
    them); an absolute ``name`` is resolved alike."""
    if "\0" in str(name):  # realpath's ValueError: no file has the name
        raise ScenarioError(f"{key}: {str(name)!r} holds a NUL, which no file name has")
    path = Path(folder) / name
    for resolved in (path, path.parent):  # a missing file: its folder resolved, the name as written
        try:
            real = Path(os.path.realpath(resolved, strict=True))
        except OSError:
            continue
        return real if resolved == path else real / path.name
    return path  # its folder missing too: as written (``gone/../x`` resolved is a file the system would not open)


# a bridge's options that name a file (its other options are the robot's own, passed on as written)
BRIDGE_FILE_OPTIONS = {"lerobot": ("units",)}


def files_beside(scenario: Scenario, folder: Path) -> Scenario:
    """``scenario`` with every file it names taken from ``folder`` (its file's real one, ``scenario_folder``) as the
    real file (``beside``), as compose files and manifests do: ``calibration``, the policy's file or folder (a source
    that ``TAKES_FILE``: ``replay:``, ``onnx:``, ``lerobot:``) and its ``?map=``, a bridge's ``?units=``. From the
    working folder, one scenario ran another calibrated profile when started from another folder."""
    from cellguard.policy.registry import source

    try:
        module = source(scenario.policy.partition(":")[0])
    except CellguardError:  # an unknown source, or its extra missing: refused as the run builds it, as before
        module = None
    update = {"policy": _spec_beside(scenario.policy, folder, module is not None and module.TAKES_FILE,
                                     ("map",) if module is not None and "map" in module.OPTIONS else (), "policy"),
              "robot": robot_beside(scenario.robot, folder)}
    if scenario.calibration is not None:
        update["calibration"] = beside(folder, scenario.calibration, "calibration")
    return scenario.model_copy(update=update)


def robot_beside(spec: str, folder: Path) -> str:
    """The robot spec ``spec`` with the files its bridge's options name taken from ``folder`` (``beside``): a
    scenario's ``robot:``, and a release run's (``release run --scenario FILE``: from ``scenario_folder(FILE)``)."""
    return _spec_beside(spec, folder, False, BRIDGE_FILE_OPTIONS.get(spec.partition(":")[0], ()), "robot")


def _spec_beside(spec: str, folder: Path, takes_file: bool, file_options: tuple[str, ...], key: str) -> str:
    """``SCHEME:TARGET?k=v`` (a scenario's ``key``) with TARGET (when ``takes_file``) and the ``file_options`` taken
    from ``folder`` (``beside``); the rest as written (a malformed spec is left for its own parser to refuse)."""
    scheme, sep, arg = spec.partition(":")
    if not sep:
        return spec
    target, q, query = arg.partition("?")
    if takes_file and target:
        target = str(beside(folder, target, key))
    pairs = parse_query(query)
    if any(k in file_options for k, _ in pairs):  # written back percent-encoded (a space as %20: a + is a +)
        query = urlencode([(k, str(beside(folder, v, f"{key} option {k}")) if k in file_options and v else v)
                           for k, v in pairs], safe="/", quote_via=quote)
    return f"{scheme}:{target}{q}{query}"


def _format_loc(loc: tuple) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif part in FAULTS or part in PROCESS_CHANGES or part in RECOVERIES or part in ("str", "list[str]"):
            continue  # pydantic's union branch names, not keys the user wrote
        else:
            out += f".{part}" if out else str(part)
    return out or "scenario"
