"""``record to-lerobot --task``: an empty or blank task is refused, not replaced by the cell's name unasked."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.runtime import run_scenario
from cellguard.scenario import parse_scenario

runner = CliRunner()


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A real run of one cycle."""
    out = tmp_path_factory.mktemp("run")
    run_scenario(parse_scenario({"cell": "arm-pick-place", "seed": 2, "policy": "scripted", "acceptance_cycles": 1,
                                 "production_cycles": 0}), out)
    return out


@pytest.mark.parametrize("task", ["", "   "])
def test_an_empty_or_blank_task_is_one_line_exit_2_and_no_dataset(folder, tmp_path, task):
    result = runner.invoke(app, ["record", "to-lerobot", str(folder), "-o", str(tmp_path / "ds"), "--task", task])
    assert result.exit_code == 2 and result.output.startswith("error: --task: ") and "blank" in result.output
    assert not (tmp_path / "ds").exists()


def test_no_task_is_the_cells_name(folder, tmp_path):
    import pyarrow.parquet as pq

    result = runner.invoke(app, ["record", "to-lerobot", str(folder), "-o", str(tmp_path / "ds")])
    assert result.exit_code == 0, result.output
    assert pq.read_table(tmp_path / "ds/meta/tasks.parquet")["__index_level_0__"].to_pylist() == ["arm pick place"]
