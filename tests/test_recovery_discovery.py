"""A new recovery behaviour is one new file: every module of the recovery package is imported and its behaviours
taken. Adding one took its file and an edit of the list in robot/recovery/__init__.py.

The package is imported in a fresh process whose package path holds a temporary folder besides its own (the
discovery path, as a plugin folder would extend it), with one behaviour module written there; a scenario then
runs it by name and the diagnosis reads its attempt back.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from cellguard.robot.recovery import RECOVERIES, back_off

BEHAVIOUR = '''
"""Go straight home after a missed grasp, at a share of the taught speed."""

from typing import Literal

from cellguard.robot.recovery.base import Plan, Recovery, go_home


class StraightHome(Recovery):
    do: Literal["straight_home"]
    needs = ("reach", "tool_taught")

    def plan(self, cell, q, attempt, origin) -> Plan:
        return go_home(cell, q, self.speed_scale)
'''

# the package imported with the temporary folder on its path, before anything else imports it
IMPORT = """
import importlib.util, json, sys
from pathlib import Path
import cellguard.robot
home = Path(cellguard.robot.__file__).parent / "recovery"
spec = importlib.util.spec_from_file_location("cellguard.robot.recovery", home / "__init__.py",
                                              submodule_search_locations=[str(home), sys.argv[1]])
package = importlib.util.module_from_spec(spec)
sys.modules[spec.name] = package
spec.loader.exec_module(package)
from cellguard.errors import ScenarioError
from cellguard.scenario import parse_scenario
"""

RUN = """
from cellguard.diagnose.recovery import attempts_of
from cellguard.runtime import Run
run = Run(parse_scenario(json.loads(sys.argv[2])))
outcome = run.cycle()
print(json.dumps({"known": list(package.RECOVERIES), "log": outcome["recovery_log"],
                  "read": [[c, o.to_dict()] for c, o in attempts_of([outcome])]}))
"""

REFUSED = """
try:
    parse_scenario(json.loads(sys.argv[2]))
except ScenarioError as exc:
    print(exc)
"""

SCENARIO = {"cell": "arm-pick-place", "seed": 5, "acceptance_cycles": 0, "production_cycles": 1,
            "faults": [{"kind": "intermittent_slip", "rate": 1.0, "dx_mm": -5.0}],
            "recovery": {"behaviours": [{"do": "straight_home", "trigger": "grasp_missed", "speed_scale": 0.8}]}}


def _python(tmp_path, script: str, scenario: dict) -> str:
    (tmp_path / "straight_home.py").write_text(BEHAVIOUR)
    done = subprocess.run([sys.executable, "-c", IMPORT + script, str(tmp_path), json.dumps(scenario)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_a_behaviour_module_dropped_into_the_package_path_runs_by_name_from_a_scenario(tmp_path):
    found = json.loads(_python(tmp_path, RUN, SCENARIO).splitlines()[-1])
    assert found["known"] == [*RECOVERIES, "straight_home"]  # the built-ins in their order, then the new one
    assert [(r["behaviour"], r["trigger"], r["outcome"]) for r in found["log"]] == [
        ("straight_home", "grasp_missed", "resumed")]
    assert found["read"] == [[0, found["log"][0]]]


@pytest.mark.parametrize("name", ["teleport", "straight-home"])
def test_an_unknown_name_is_one_error_listing_every_known_one_the_new_one_too(tmp_path, name):
    scenario = {**SCENARIO, "recovery": {"behaviours": [{"do": name, "trigger": "grasp_missed"}]}}
    known = ", ".join(repr(n) for n in [*RECOVERIES, "straight_home"])
    assert _python(tmp_path, REFUSED, scenario).strip() == (
        f"scenario: recovery.behaviours[0]: unknown recovery; known: {known}")


def test_the_built_in_behaviours_keep_their_names_and_order():
    assert list(RECOVERIES) == ["retry_grasp", "back_off", "rehome", "reregister_datum", "operator"]


@pytest.mark.parametrize(("do", "error"), [
    ('Literal["back_off"]', "recovery behaviour 'back_off' is defined twice: "
                            f"cellguard.robot.recovery.back_off.BackOff ({back_off.__file__}) and "
                            "cellguard.robot.recovery.straight_home.StraightHome"),
    ("str", "recovery behaviour cellguard.robot.recovery.straight_home.StraightHome: do must be "
            "Literal['a_name']"),
])
def test_a_behaviour_module_that_takes_a_name_twice_or_none_is_refused_naming_it(tmp_path, do, error):
    (tmp_path / "straight_home.py").write_text(BEHAVIOUR.replace('Literal["straight_home"]', do))
    done = subprocess.run([sys.executable, "-c", IMPORT, str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 1 and done.stderr.strip().splitlines()[-1] == (
        f"cellguard.plugins.PluginError: {tmp_path / 'straight_home.py'}: {error}")
