"""Checks on what a CLI command printed, and a small recorded run, shared by the CLI tests."""

from __future__ import annotations

from pathlib import Path

import yaml
from typer.testing import CliRunner

from cellguard.cli import app

FIXTURE_SHIFT_RUN = {"cell": "arm-pick-place", "seed": 3, "acceptance_cycles": 6, "production_cycles": 4,
                     "faults": [{"kind": "fixture_shift", "at_cycle": 7, "dx_mm": 4.0}]}


def one_error(result) -> str:
    """The one ``error:`` line of a typer CliRunner result that exited 2 without a traceback."""
    assert result.exception is None or isinstance(result.exception, SystemExit), result.output
    assert result.exit_code == 2, result.output
    lines = result.output.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.output
    return lines[0]


def record_run(root: Path, scenario: dict = FIXTURE_SHIFT_RUN) -> Path:
    """``cellguard run`` of ``scenario`` into ``root/out`` (asserted to exit 0); the run folder."""
    (root / "scenario.yaml").write_text(yaml.safe_dump(scenario))
    result = CliRunner().invoke(app, ["run", str(root / "scenario.yaml"), "--out", str(root / "out"), "--json"])
    assert result.exit_code == 0, result.output
    return root / "out"
