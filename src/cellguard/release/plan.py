"""The release plan: per stage, the runs that make its evidence and the gates they must pass.

```yaml
stages:
  sim:                              # the testnet: a scenario suite, fault scenarios included
    runs:
      - {name: nominal, seed: 5, acceptance_cycles: 3}
      - {name: fixture-1.5mm, seed: 6, acceptance_cycles: 3,
         faults: [{kind: fixture_shift, at_cycle: 0, dx_mm: -1.5}]}
    gates:
      - {metric: success_rate, min: 1.0, min_cycles: 6}
      - {metric: protective_stops, max: 0}
  bench: {clock: wall, runs: [...], gates: [...]}
  pilot: {shadow: true, runs: [...], gates: [...]}
  production: {runs: [...], gates: [...]}
```

A run entry is a scenario without ``cell``, ``policy``, ``guard`` and ``calibration``: those come
from the release; ``production_cycles`` defaults to 0. A file its ``robot`` names (``?units=``) is the one beside
the plan file, as a scenario's files are beside it, from whatever folder the release runs (``run_beside``); the plan
is hashed as written (a site's logged plan stays the same plan wherever its file lies), and what makes its runs and
judges its passes with what those files hold (``robot_files``: the same plan beside another units map makes other
runs, and another plan to pass; one that cannot be read is one error naming it). Read with the project's YAML
loader; an unknown metric, key or stage is one line.
The file is checked on no cell when it is read; ``check_cell`` checks a stage against its cell (the faults it can
simulate, the metrics it reports) at ``promote`` and before the stage's first run. The packaged plan is one per kind
of cell (``default_plan``): a pick-place cell's, with a moved fixture and the place error, and one for every other.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, ValidationError

from cellguard.errors import ScenarioError
from cellguard.options import parse_query
from cellguard.release.errors import GateError
from cellguard.release.gates import Gate, gate_error
from cellguard.release.metrics import METRICS, PICK_PLACE
from cellguard.release.store import STAGES
from cellguard.robot.registry import make_cell
from cellguard.scenario import BRIDGE_FILE_OPTIONS, Scenario, parse_scenario, robot_beside, scenario_folder
from cellguard.yaml_file import read_bounded, read_yaml, reject_unknown_keys

PLANS = Path(__file__).parents[1] / "scenarios"
PICK_PLACE_PLAN = PLANS / "release-plan.yaml"
ANY_CELL_PLAN = PLANS / "release-plan-any-cell.yaml"
RUN_KEYS = ("name", "seed", "acceptance_cycles", "production_cycles", "policy_hz", "site", "cell_id", "faults", "robot",
            "realtime", "cycle")
RUN_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")  # a run's folder is named after it: no path, no escapes


class StagePlan(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    clock: Literal["simulated", "wall"] = "simulated"
    shadow: bool = False
    runs: list[dict] = Field(default_factory=list)
    gates: list[Gate] = Field(default_factory=list)
    # the plan file's real folder: its runs' robot files are taken beside it (``runs_beside``), never hashed (a plan
    # logged, then moved with its site, or one in two folders, is the same plan); what they hold is (``robot_files``)
    _folder: Path | None = PrivateAttr(default=None)

    def runs_beside(self) -> list[dict]:
        """The runs as they are run: the files their robots name taken beside the plan file (``run_beside``); as
        written for a plan not read from a file."""
        if self._folder is None:
            return self.runs
        return [run_beside(run, self._folder, f"runs[{i}]") for i, run in enumerate(self.runs)]


def robot_files(runs: list[dict]) -> list[list]:
    """[run index, option, sha256] of each file the robots of ``runs`` (as run: ``runs_beside``) name (a bridge's
    ``?units=``): what those runs are made with besides the plan's text. A file that cannot be read is a GateError
    naming it: keyed by its text alone, the plan counted runs made under any units map, and judged a pass so."""
    files = []
    for i, option, path in _named_files(runs):
        try:
            data = read_bounded(path, option, GateError)
        except GateError as exc:
            raise GateError(f"release plan run {runs[i].get('name', 'run')!r}: {exc}; the plan's runs are made with "
                            f"what it holds: none is run, counted or judged without it") from None
        files.append([i, option, hashlib.sha256(data).hexdigest()])
    return files


def robot_file_paths(runs: list[dict]) -> list[str]:
    """Each file the robots of ``runs`` name (``robot_files``), as a refusal names it."""
    return [str(path) for _, _, path in _named_files(runs)]


def _named_files(runs: list[dict]) -> Iterator[tuple[int, str, Path]]:
    """(run index, option, path) of each file a bridge option of a robot of ``runs`` names (``BRIDGE_FILE_OPTIONS``)."""
    for i, run in enumerate(runs):
        spec = run.get("robot") if isinstance(run, dict) else None
        if not isinstance(spec, str):
            continue
        scheme, _, arg = spec.partition(":")
        for option, value in parse_query(arg.partition("?")[2]):
            if option in BRIDGE_FILE_OPTIONS.get(scheme, ()) and value:
                yield i, option, Path(value)


def default_plan(cell: str) -> Path:
    """The packaged plan for ``cell``: the pick-place one where the cell has a part to place (a moved fixture, the
    place error), else the one any cell can run (one plan for all ran the quadruped's sim stage into a fault it
    cannot simulate)."""
    return PICK_PLACE_PLAN if PICK_PLACE.met_by(make_cell(cell)) else ANY_CELL_PLAN


def plan_in_force(site: Path, cell: str) -> dict[str, StagePlan]:
    """The plan in force at ``site`` for ``cell``: the site's release-plan.yaml, else the packaged plan for the
    cell's kind. What every command judges a pass by, whatever ``--plan`` it was given. Anything at the name is
    the site's plan: a folder or a dangling link there is an error (passed over, it put the packaged gates in force
    without a word)."""
    path = Path(site) / "release-plan.yaml"
    return load_plan(path if path.exists() or path.is_symlink() else default_plan(cell))


def load_plan(path: Path) -> dict[str, StagePlan]:
    """Every stage's plan from ``path``; a stage left out has no runs."""
    path = Path(path)
    raw = read_yaml(path, "release plan", GateError)
    if not isinstance(raw, dict) or not isinstance(raw.get("stages"), dict):
        raise GateError(f"{path}: stages: expected a mapping of stage name to its runs and gates")
    reject_unknown_keys(raw, ["stages"], f"{path}: ", GateError)
    reject_unknown_keys(raw["stages"], STAGES, f"{path}: stages.", GateError)
    plans, folder = {}, scenario_folder(path)
    for stage in STAGES:
        spec = raw["stages"].get(stage)
        spec = {} if spec is None else spec  # ``sim:`` left empty; ``sim: false`` is no mapping
        where = f"{path}: stages.{stage}"
        if not isinstance(spec, dict):
            raise GateError(f"{where}: expected a mapping with runs and gates")
        gates = spec.get("gates")
        for i, gate in enumerate(gates if isinstance(gates, list) else []):  # else StagePlan names it, not a TypeError
            try:
                Gate.model_validate(gate)
            except ValidationError as exc:
                raise gate_error(f"{where}.gates[{i}]", exc) from None
        try:
            plans[stage] = StagePlan.model_validate(spec)
        except ValidationError as exc:
            raise gate_error(where, exc) from None
        plans[stage]._folder = folder
        for i, run in enumerate(plans[stage].runs):
            check_run(run_beside(run, folder, f"{where}.runs[{i}]"), f"{where}.runs[{i}]")
        for i, gate in enumerate(plans[stage].gates):
            if METRICS[gate.metric].shadow and not plans[stage].shadow:
                raise GateError(f"{where}.gates[{i}].metric: {gate.metric} is measured on shadow runs only and this "
                                f"stage has no shadow: true; the gate could only end inconclusive")
        if plans[stage].runs and not plans[stage].gates:
            raise GateError(f"{where}: runs but no gates; they could only end inconclusive")
    return plans


def run_beside(run: object, folder: Path, where: str) -> object:
    """``run`` with the files its ``robot`` names taken from ``folder`` (``robot_beside``): a plan's runs from the
    plan file's real folder (``scenario_folder``), as ``release run --scenario FILE`` takes its run's from FILE's.
    From the working folder, a plan started elsewhere read another units map, or none. Anything but a run with a
    robot spec is returned as it is, for ``check_run`` to refuse or pass."""
    if not (isinstance(run, dict) and isinstance(run.get("robot"), str)):
        return run
    try:
        return {**run, "robot": robot_beside(run["robot"], folder)}
    except ScenarioError as exc:
        raise GateError(f"{where}: {exc}") from None


def check_run(run: dict, where: str) -> None:
    """A run entry's keys and values, on no cell in particular (``check_cell`` checks it against its cell)."""
    if not isinstance(run, dict):
        raise GateError(f"{where}: expected a mapping of scenario keys")
    reject_unknown_keys(run, RUN_KEYS, f"{where}.", GateError)
    name = run.get("name", "run")
    if not (isinstance(name, str) and RUN_NAME.fullmatch(name)):
        raise GateError(f"{where}.name: {repr(name)[:80]} is not a run name (1 to 64 of A-Z a-z 0-9 . _ -, "
                        f"not starting with . _ -): it names the run's folder")
    scenario_for(run, "arm-pick-place", "scripted", {}, origin=where)


def check_cell(plan: StagePlan, cell: str, stage: str, runs: list[dict] | None = None) -> None:
    """GateError naming the first of the stage's runs (``runs`` in place of the plan's) that ``cell`` cannot
    simulate (a fault it does not have, a cycle end it cannot tell), or its first gate on a metric the cell never
    reports. Called at ``promote`` and before the stage's first run: the runtime's check of each run as it starts
    refused a later run after the earlier ones had run, and such a gate could only end inconclusive."""
    from cellguard.runtime.cycles import make_cycle_source

    robot = make_cell(cell)
    for run in plan.runs_beside() if runs is None else runs:
        name = run.get("name", "run")
        scenario = scenario_for(run, cell, "scripted", {}, origin=f"{stage} run {name!r}")
        try:
            if scenario.robot == "sim":  # as the runtime: a bridge is no simulated cell to check against
                scenario.check_against(robot)
                if scenario.cycle.source != "policy":  # the policy's episode end: checked as its run loads it
                    make_cycle_source(scenario.cycle, robot, None)
        except ScenarioError as exc:
            raise GateError(f"{stage} run {name!r}: {exc}") from None
    for i, gate in enumerate(plan.gates):
        needs = METRICS[gate.metric].needs
        if needs is not None and not needs.met_by(robot):
            raise GateError(f"stages.{stage}.gates[{i}].metric: {gate.metric} needs {needs.what}; cell {cell!r} has "
                            f"none, so the gate could only end inconclusive")


def scenario_for(run: dict, cell: str, policy: str, guard: dict, calibration: str | None = None,
                 origin: str = "run") -> Scenario:
    """The scenario of one run entry for a release (its cell, policy, envelope and calibrated profile)."""
    fields = {"production_cycles": 0, **{k: v for k, v in run.items() if k != "name"}}
    return parse_scenario({**fields, "cell": cell, "policy": policy, "guard": guard, "calibration": calibration},
                          origin=origin)
