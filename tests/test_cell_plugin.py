"""A new cell is one file in its own package, found through the entry-point group ``cellguard.cells``.

A probe's copy of the arm with a new name could not be run: ``make_cell`` knew only a dict inside cellguard,
``scripted`` only another, and a record of the new cell could not be re-fitted or replayed in a later process.
The plugin here is a real distribution on ``sys.path`` (a ``.dist-info`` with ``entry_points.txt``), found by
``importlib.metadata`` as an installed package is.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from cellguard.errors import ConfigError, UnknownNameError
from cellguard.policy.registry import make_policy
from cellguard.robot.registry import cell_names, make_cell

NAME = "armcopy-pick-place"
PLUGIN = f'''
from cellguard.robot.arm_cell import ArmPickPlace


class ArmCopy(ArmPickPlace):
    """The arm cell under another name, as a site's own robot would be."""
    name = "{NAME}"


def scripted(cell):
    from cellguard.policy.scripted_arm import ScriptedArmPolicy
    return ScriptedArmPolicy(calibration=cell.context())
'''


def install(folder: Path, entry_points: str, module: str | None = PLUGIN, dist: str = "armcopy") -> Path:
    """A distribution ``dist`` in ``folder`` (made): its module (none: entry points only) and its metadata."""
    folder.mkdir()
    if module is not None:
        (folder / f"{dist}.py").write_text(module)
    info = folder / f"{dist}-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(entry_points)
    return folder


ENTRY_POINTS = f"[cellguard.cells]\n{NAME} = armcopy:ArmCopy\n\n[cellguard.scripted_policies]\n{NAME} = armcopy:scripted\n"


@pytest.fixture
def plug(tmp_path, monkeypatch):
    """Installs a distribution on ``sys.path`` (``install``'s arguments); its module is forgotten afterwards."""
    def put(entry_points: str, module: str | None = PLUGIN, dist: str = "armcopy") -> Path:
        folder = install(tmp_path / dist, entry_points, module, dist)
        monkeypatch.syspath_prepend(str(folder))
        return folder

    yield put
    sys.modules.pop("armcopy", None)


@pytest.fixture
def plugin(plug):
    return plug(ENTRY_POINTS)


def test_a_plugin_cell_and_its_taught_program_are_found_by_name(plugin):
    cell = make_cell(NAME, seed=3)
    assert type(cell).__name__ == "ArmCopy" and cell.name == NAME and NAME in cell_names()
    policy = make_policy("scripted", cell)
    assert type(policy).__name__ == "ScriptedArmPolicy"


def test_an_unknown_cell_lists_the_plugins_too(plugin):
    with pytest.raises(UnknownNameError, match=NAME):
        make_cell("no-such-cell")


def test_a_plugin_that_cannot_be_imported_is_one_line_naming_it(plug):
    plug(ENTRY_POINTS, module="raise RuntimeError('the vendor SDK is missing')\n")
    with pytest.raises(ConfigError, match=r"armcopy:ArmCopy.*RuntimeError: the vendor SDK is missing"):
        make_cell(NAME)


def test_a_plugin_whose_class_has_another_name_is_refused(plug):
    plug(ENTRY_POINTS.replace(f"{NAME} = armcopy:ArmCopy", "other-name = armcopy:ArmCopy"))
    with pytest.raises(ConfigError, match="must be the cell's name"):
        make_cell("other-name")


def test_a_plugin_cell_runs_and_its_record_is_diagnosed_in_later_processes(plugin, tmp_path):
    scenario = tmp_path / "s.yaml"
    scenario.write_text(f"cell: {NAME}\nseed: 1\npolicy: scripted\nacceptance_cycles: 5\nproduction_cycles: 1\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(plugin), os.environ.get("PYTHONPATH", "")])}
    cli = [sys.executable, "-c", "from cellguard.cli import app; app()"]
    ran = subprocess.run([*cli, "run", str(scenario), "--out", str(tmp_path / "out")], env=env,
                         capture_output=True, text=True, timeout=600)
    assert ran.returncode == 0, ran.stderr
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["scenario"]["cell"] == NAME and len(summary["cycles"]) == 6
    diagnosed = subprocess.run([*cli, "diagnose", str(tmp_path / "out"), "--json"], env=env, capture_output=True,
                               text=True, timeout=600)
    assert diagnosed.returncode == 0, diagnosed.stderr
    assert json.loads(diagnosed.stdout)["findings"] == []


BROKEN = f'''
from cellguard.robot.arm_cell import ArmPickPlace


class NoBus(ArmPickPlace):
    name = "{NAME}"

    def __init__(self, seed=0):
        raise OSError("cannot open /dev/ttyUSB0")


class NotACell:
    name = "{NAME}"

    def __init__(self, seed=0):
        pass


def junk(cell):
    return 42


class LazyFaults(ArmPickPlace):
    name = "{NAME}"

    @property
    def supported_faults(self):
        raise RuntimeError("the fault table is read from the vendor SDK")
'''


@pytest.mark.parametrize("value, error", [
    ("armcopy:NoBus", r"cell 'armcopy-pick-place': its plugin armcopy \(\S+armcopy\.py\) failed: OSError: cannot open "
                      r"/dev/ttyUSB0"),
    ("armcopy:NotACell", r"returned a NotACell, not a SimCell: it has no begin_cycle, .*profile"),
])
def test_a_plugin_cell_that_cannot_be_built_is_one_line_naming_it(plug, value, error):
    """Imported, then failing (a vendor SDK that cannot open its bus) or not a cell: a traceback, exit 1, before."""
    plug(f"[cellguard.cells]\n{NAME} = {value}\n", module=BROKEN)
    with pytest.raises(ConfigError, match=error):
        make_cell(NAME)


def test_a_plugin_taught_program_that_is_no_policy_is_one_line_naming_it(plug):
    plug(ENTRY_POINTS.replace("armcopy:scripted", "armcopy:junk"), module=PLUGIN + BROKEN)
    with pytest.raises(ConfigError, match=r"scripted policy for cell 'armcopy-pick-place': its plugin armcopy "
                                          r"returned a int, not a Policy: it has no close, content_hash"):
        make_policy("scripted", make_cell(NAME))


def test_a_cell_name_two_plugins_register_is_refused_naming_both(plugin, plug):
    """Which one won followed the order the folders were listed in: a record could read as another robot."""
    plug(f"[cellguard.cells]\n{NAME} = othercopy:Quadruped\n", module=None, dist="othercopy")
    with pytest.raises(ConfigError, match=rf"cellguard.cells '{NAME}': registered twice, as .* and as .*; "
                                          r"uninstall one of the two plugins"):
        make_cell(NAME)


def test_a_plugin_cell_whose_member_raises_when_read_is_not_a_traceback(plug):
    """The member check ran a property that raised: a traceback, exit 1. Members are looked up, not run."""
    plug(f"[cellguard.cells]\n{NAME} = armcopy:LazyFaults\n", module=BROKEN)
    cell = make_cell(NAME)
    assert type(cell).__name__ == "LazyFaults"


def test_a_name_two_plugins_register_leaves_every_other_name_as_it_was(plugin, plug):
    """The conflict was raised while listing the group: every cell, built-in ones included, was refused."""
    plug(f"[cellguard.cells]\n{NAME} = othercopy:Quadruped\n", module=None, dist="othercopy")
    assert make_cell("arm-pick-place").name == "arm-pick-place" and NAME in cell_names()
    with pytest.raises(UnknownNameError, match="arm-pick-place"):
        make_cell("arm-pick-plac")
