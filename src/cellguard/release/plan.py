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
from the release; ``production_cycles`` defaults to 0. Read with the project's YAML loader; an unknown metric, key or stage is one line.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from cellguard.release.errors import GateError
from cellguard.release.gates import Gate, gate_error
from cellguard.release.store import STAGES
from cellguard.scenario import Scenario, parse_scenario
from cellguard.yaml_file import read_yaml, reject_unknown_keys

DEFAULT_PLAN = Path(__file__).parents[1] / "scenarios" / "release-plan.yaml"
RUN_KEYS = ("name", "seed", "acceptance_cycles", "production_cycles", "policy_hz", "site", "cell_id", "faults", "robot",
            "realtime", "cycle")
RUN_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")  # a run's folder is named after it: no path, no escapes


class StagePlan(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    clock: Literal["simulated", "wall"] = "simulated"
    shadow: bool = False
    runs: list[dict] = Field(default_factory=list)
    gates: list[Gate] = Field(default_factory=list)


def load_plan(path: Path | None = None) -> dict[str, StagePlan]:
    """Every stage's plan from ``path`` (the packaged plan when None); a stage left out has no runs."""
    path = Path(path) if path is not None else DEFAULT_PLAN
    raw = read_yaml(path, "release plan", GateError)
    if not isinstance(raw, dict) or not isinstance(raw.get("stages"), dict):
        raise GateError(f"{path}: stages: expected a mapping of stage name to its runs and gates")
    reject_unknown_keys(raw, ["stages"], f"{path}: ", GateError)
    reject_unknown_keys(raw["stages"], STAGES, f"{path}: stages.", GateError)
    plans = {}
    for stage in STAGES:
        spec = raw["stages"].get(stage) or {}
        where = f"{path}: stages.{stage}"
        if not isinstance(spec, dict):
            raise GateError(f"{where}: expected a mapping with runs and gates")
        for i, gate in enumerate(spec.get("gates") or []):
            try:
                Gate.model_validate(gate)
            except ValidationError as exc:
                raise gate_error(f"{where}.gates[{i}]", exc) from None
        try:
            plans[stage] = StagePlan.model_validate(spec)
        except ValidationError as exc:
            raise gate_error(where, exc) from None
        for i, run in enumerate(plans[stage].runs):
            check_run(run, f"{where}.runs[{i}]")
        if plans[stage].runs and not plans[stage].gates:
            raise GateError(f"{where}: runs but no gates; they could only end inconclusive")
    return plans


def check_run(run: dict, where: str) -> None:
    if not isinstance(run, dict):
        raise GateError(f"{where}: expected a mapping of scenario keys")
    reject_unknown_keys(run, RUN_KEYS, f"{where}.", GateError)
    name = run.get("name", "run")
    if not (isinstance(name, str) and RUN_NAME.fullmatch(name)):
        raise GateError(f"{where}.name: {repr(name)[:80]} is not a run name (1 to 64 of A-Z a-z 0-9 . _ -, "
                        f"not starting with . _ -): it names the run's folder")
    scenario_for(run, "arm-pick-place", "scripted", {}, origin=where)


def scenario_for(run: dict, cell: str, policy: str, guard: dict, calibration: str | None = None,
                 origin: str = "run") -> Scenario:
    """The scenario of one run entry for a release (its cell, policy, envelope and calibrated profile)."""
    fields = {"production_cycles": 0, **{k: v for k, v in run.items() if k != "name"}}
    return parse_scenario({**fields, "cell": cell, "policy": policy, "guard": guard, "calibration": calibration},
                          origin=origin)
