"""Scenario files: which cell, which policy, how many cycles, which faults to inject.

Validated before anything runs: an unknown key, a wrong type or an impossible value raises
ScenarioError naming the key (``faults[1].dx_mm: ...``).
"""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from cellguard.control.settings import GuardSettings
from cellguard.errors import ScenarioError
from cellguard.robot.faults import FAULTS, AnyFault
from cellguard.robot.process import PROCESS_CHANGES, AnyProcessChange, declared_changes
from cellguard.yaml_file import read_yaml


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
    faults: list[AnyFault] = Field(default_factory=list)
    process_changes: list[AnyProcessChange] = Field(default_factory=list)
    guard: GuardSettings = Field(default_factory=GuardSettings)

    @property
    def total_cycles(self) -> int:
        return self.acceptance_cycles + self.production_cycles

    def declared_process(self, cycle: int) -> list[dict]:
        """The process changes declared by ``cycle`` (what the record's context says; undeclared ones stay out)."""
        return declared_changes(self.process_changes, cycle)

    def check_against(self, cell) -> None:
        """Refuse faults the cell cannot simulate and joints its profile does not have."""
        for i, fault in enumerate(self.faults):
            if fault.kind not in cell.supported_faults:
                raise ScenarioError(
                    f"faults[{i}].kind: {fault.kind!r} cannot be simulated in cell {cell.name!r}; "
                    f"it supports: {', '.join(sorted(cell.supported_faults))}"
                )
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


def parse_scenario(raw: object, origin: str = "scenario") -> Scenario:
    """Validate a decoded YAML document; raise ScenarioError naming the first bad key."""
    if not isinstance(raw, dict):
        raise ScenarioError(f"{origin}: expected a mapping of keys, got {type(raw).__name__}")
    try:
        return Scenario.model_validate(raw)
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = _format_loc(err["loc"])
        msg = err["msg"]
        if err["type"] == "extra_forbidden":
            msg = "unknown key"
        elif err["type"] == "union_tag_invalid":
            known = "fault" if loc.startswith("faults") else "process change"
            msg = f"unknown {known} kind; known: {err['ctx']['expected_tags']}"
        raise ScenarioError(f"{origin}: {loc}: {msg}") from None


def load_scenario(path: Path) -> Scenario:
    """Read and validate a scenario file."""
    return parse_scenario(read_yaml(path, "scenario", ScenarioError), origin=str(path))


def _format_loc(loc: tuple) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif part in FAULTS or part in PROCESS_CHANGES or part in ("str", "list[str]"):
            continue  # pydantic's union branch names, not keys the user wrote
        else:
            out += f".{part}" if out else str(part)
    return out or "scenario"
