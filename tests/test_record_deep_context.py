"""A run whose context nests a value past what the record's readers take (``json_values.MAX_DEPTH``) is refused
before anything runs, naming the key: a plugin cell whose own description nested 150 deep was recorded, and the
run's own record then read as damaged, its context lost (``diagnose``: "the context record is missing"). A value
just within the bound records and reads back whole."""

from __future__ import annotations

import sys

import pytest
import yaml
from test_cell_plugin import install
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.record.json_values import MAX_DEPTH
from cellguard.record.reader import open_record

PLUGIN = '''
from cellguard.robot.arm_cell import ArmPickPlace

DEPTH = {depth}


class DeepArm(ArmPickPlace):
    """The arm cell whose context carries notes nested DEPTH lists deep."""
    name = "deep-arm"

    def context(self):
        notes = "leaf"
        for _ in range(DEPTH):
            notes = [notes]
        return {{**super().context(), "plugin_notes": notes}}


def scripted(cell):
    from cellguard.policy.scripted_arm import ScriptedArmPolicy
    return ScriptedArmPolicy(calibration=ArmPickPlace.context(cell))
'''
ENTRY_POINTS = "[cellguard.cells]\ndeep-arm = deeparm:DeepArm\n\n[cellguard.scripted_policies]\ndeep-arm = deeparm:scripted\n"


def _run(tmp_path, monkeypatch, depth: int):
    monkeypatch.syspath_prepend(str(install(tmp_path / "plugin", ENTRY_POINTS, PLUGIN.format(depth=depth),
                                            "deeparm")))
    scenario = tmp_path / "s.yaml"
    scenario.write_text(yaml.safe_dump({"cell": "deep-arm", "policy": "scripted", "acceptance_cycles": 1,
                                        "production_cycles": 0}))
    try:
        return CliRunner().invoke(app, ["run", str(scenario), "--out", str(tmp_path / "run")])
    finally:
        sys.modules.pop("deeparm", None)


@pytest.mark.parametrize("depth", [MAX_DEPTH - 1, 150])  # one level more than reads whole
def test_a_context_nested_past_the_readers_bound_is_refused_before_the_run(tmp_path, monkeypatch, depth):
    result = _run(tmp_path, monkeypatch, depth)
    assert result.exit_code == 2 and result.stdout == "", result.output
    assert result.stderr.count("\n") == 1 and "nests 'plugin_notes' deeper than 100 levels" in result.stderr
    assert "nothing was run" in result.stderr and not (tmp_path / "run" / "record.mcap").exists()


@pytest.mark.parametrize("depth", [MAX_DEPTH - 2])
def test_a_context_just_within_the_bound_records_and_reads_whole(tmp_path, monkeypatch, depth):
    result = _run(tmp_path, monkeypatch, depth)
    assert result.exit_code == 0, result.output
    with open_record(tmp_path / "run") as record:
        notes = record.context["plugin_notes"]
        health = record.health()
        assert health.ok and not health.off_schema, health
    for _ in range(depth):
        notes = notes[0]
    assert notes == "leaf"
