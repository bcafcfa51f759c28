"""A new fault kind or process change is one new file: the packages find every module that defines one (adding one
took its file plus an edit of the package's list, and of the diagnosis for a process change)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from cellguard.errors import ScenarioError
from cellguard.plugins import PluginError
from cellguard.robot.faults import FAULTS, Fault
from cellguard.robot.kinds import discover
from cellguard.robot.process import PROCESS_CHANGES
from cellguard.scenario import parse_scenario

TESTS = Path(__file__).parent
NUDGE = '''
    """A fixture knocked by dx_mm from at_cycle on: a fault kind cellguard does not ship."""
    from typing import Literal

    import numpy as np

    from cellguard.robot.faults.base import Fault


    class FixtureNudge(Fault):
        kind: Literal["fixture_nudge"]
        at_cycle: int = 0
        dx_mm: float = 1.0

        def apply(self, cell, cycle: int) -> None:
            cell.set_fixture_offset(np.array([self.dx_mm * 1e-3 * (cycle >= self.at_cycle), 0.0, 0.0]))
'''
GRIPPER = '''
    """A heavier gripper fitted: a process change cellguard does not ship, conditioned on as a payload is."""
    from typing import ClassVar, Literal

    from cellguard.robot.process.base import ProcessChange


    class NewGripper(ProcessChange):
        kind: Literal["new_gripper"]
        grams: float = 100.0
        hook: ClassVar[str] = "set_payload"
        diagnosis: ClassVar[str] = "rebase"

        def apply(self, cell, cycle: int) -> None:
            if cycle >= self.at_cycle:
                cell.set_payload(self.grams * 1e-3)
'''
# run in a fresh interpreter: the scenario's schema is built from the kinds found when cellguard is imported
SCRIPT = '''
    import importlib.machinery, json, sys

    FOLDERS = {"cellguard.robot.faults": sys.argv[1], "cellguard.robot.process": sys.argv[2]}


    class OneFolderMore:
        """Finds each package of FOLDERS on one folder more, as if the file were in it, from its first import on (the
        built-in cells, imported first, take every fault kind found then)."""

        def find_spec(self, name, path, target=None):
            if name not in FOLDERS:
                return None
            spec = importlib.machinery.PathFinder.find_spec(name, path)
            spec.submodule_search_locations.append(FOLDERS[name])
            return spec


    sys.meta_path.insert(0, OneFolderMore())

    from cellguard.diagnose import diagnose
    from cellguard.errors import ScenarioError
    from cellguard.runtime import Run
    from cellguard.scenario import parse_scenario

    scenario = parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 0,
                               "faults": [{"kind": "fixture_nudge", "dx_mm": 3.0}],
                               "process_changes": [{"kind": "new_gripper", "at_cycle": 0, "grams": 40.0}]})
    run = Run(scenario)
    run.cycle()
    cell = run.cell
    try:
        parse_scenario({"cell": "arm-pick-place", "faults": [{"kind": "meteor"}]})
    except ScenarioError as exc:
        unknown = str(exc)
    sys.path.insert(0, sys.argv[3])
    from test_diagnose_power import _carry_load, record

    undeclared = diagnose(record(1, change=_carry_load))  # the same heavier load, nobody told the record
    d = diagnose(record(1, change=_carry_load), [], {"process": [{"kind": "new_gripper", "at_cycle": 30,
                                                                  "grams": 40.0}]})
    print(json.dumps({
        "fixture_mm": float((cell.data.mocap_pos[0] - cell.nominal["fixture"])[0] * 1e3),
        "part_kg": float(cell.model.body_mass[cell._part_body]), "declared": scenario.declared_process(0),
        "cycles": len(run.cycles), "unknown": unknown,
        "notes": [p.to_dict() for p in d.process], "findings": [f.cause for f in d.findings],
        "alarms": len(d.drift.alarms), "undeclared": [f.cause for f in undeclared.findings]}))
'''


def _module(folder: Path, name: str, source: str) -> Path:
    folder.mkdir(exist_ok=True)
    (folder / f"{name}.py").write_text(textwrap.dedent(source))
    return folder


def test_a_fault_and_a_process_change_in_files_of_their_own_run_from_a_scenario(tmp_path):
    faults = _module(tmp_path / "faults", "fixture_nudge", NUDGE)
    process = _module(tmp_path / "process", "new_gripper", GRIPPER)
    script = tmp_path / "run_new_kinds.py"
    script.write_text(textwrap.dedent(SCRIPT))
    done = subprocess.run([sys.executable, str(script), str(faults), str(process), str(TESTS)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    out = json.loads(done.stdout.strip().splitlines()[-1])
    assert out["cycles"] == 1 and out["fixture_mm"] == pytest.approx(3.0)
    assert out["part_kg"] == pytest.approx(0.09)  # the 50 g part and the 40 g the change added
    assert out["declared"] == [{"kind": "new_gripper", "at_cycle": 0, "grams": 40.0}]
    # an unknown kind still names every known one: the shipped ones in their order, then the new one
    assert out["unknown"].endswith("known: " + ", ".join(repr(k) for k in [*FAULTS, "fixture_nudge"]))
    # the diagnosis conditions on the new change by its class's own ``diagnosis``, with no edit of its own: the load
    # that is a load change undeclared is, declared, neither a finding nor an alarm
    assert out["undeclared"] == ["load_change"] and (out["findings"], out["alarms"]) == ([], 0)
    (note,) = out["notes"]
    assert note["kind"] == "new_gripper" and note["text"].startswith("new_gripper declared at cycle 30: ")
    assert "re-baselined" in note["text"]


def test_the_shipped_kinds_keep_their_names_order_and_error():
    assert list(FAULTS) == ["fixture_shift", "friction_growth", "servo_gain", "camera_shift", "tool_slip",
                            "policy_latency", "policy_nan", "friction_step", "intermittent_slip", "part_misplaced",
                            "late_recovery"]
    assert list(PROCESS_CHANGES) == ["payload", "warmup"]
    with pytest.raises(ScenarioError) as caught:
        parse_scenario({"cell": "arm-pick-place", "process_changes": [{"kind": "new_batch", "at_cycle": 1}]})
    assert str(caught.value) == "scenario: process_changes[0]: unknown process change kind; known: 'payload', 'warmup'"


def test_two_modules_claiming_one_kind_are_named(tmp_path, monkeypatch):
    package = _module(tmp_path / "twice_kinds", "__init__", "")
    for name in ("first", "second"):
        _module(package, name, NUDGE)
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(PluginError, match=f"^{re.escape(str(package / 'second.py'))}: "
                                          r"fault kind 'fixture_nudge' is defined twice: twice_kinds\.first\."
                                          rf"FixtureNudge \({re.escape(str(package / 'first.py'))}\) and "
                                          r"twice_kinds\.second\.FixtureNudge$"):
        discover("twice_kinds", [str(package)], Fault, "fault kind")


def test_a_kind_whose_name_is_not_one_literal_is_named(tmp_path, monkeypatch):
    package = _module(tmp_path / "loose_kinds", "__init__", "")
    _module(package, "loose", NUDGE.replace('Literal["fixture_nudge"]', "str"))
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(PluginError, match=f"^{re.escape(str(package / 'loose.py'))}: "
                                          r"fault kind loose_kinds\.loose\.FixtureNudge: kind must be "
                                          r"Literal\['a_name'\]$"):
        discover("loose_kinds", [str(package)], Fault, "fault kind")


def test_a_kind_imported_into_another_module_and_a_base_with_no_kind_are_not_found_again(tmp_path, monkeypatch):
    package = _module(tmp_path / "reuse_kinds", "__init__", "")
    _module(package, "nudge", NUDGE)
    _module(package, "variant", """
        from cellguard.robot.faults.intermittent import IntermittentOffset
        from reuse_kinds.nudge import FixtureNudge

        class Base(IntermittentOffset):
            setter = "set_fixture_offset"
    """)
    monkeypatch.syspath_prepend(str(tmp_path))
    found = discover("reuse_kinds", [str(package)], Fault, "fault kind")
    assert list(found) == ["fixture_nudge"] and found["fixture_nudge"].__module__ == "reuse_kinds.nudge"
