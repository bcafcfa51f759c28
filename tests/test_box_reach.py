"""A workspace box whose wall lies more than the tool's reach beyond where the tool gets is refused, naming the axis
and the numbers: the bound of ten times the tool's distance from the origin took a box in decimetres on the arm and a
10 m box on a decimetre-scale arm, whose walls the tool never comes near (the workspace check off, with no word)."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cellguard.control.config import GuardConfig
from cellguard.control.reach import MARGIN
from cellguard.control.settings import REACH_SAMPLES, build_guard, check_box_reach
from cellguard.embodiment import Profile
from cellguard.errors import ConfigError
from cellguard.robot.registry import cell_names, make_cell
from cellguard.scenario import load_scenario

ARM = make_cell("arm-pick-place")
ROOT = Path(__file__).parents[1]
SCENARIOS = sorted(p for folder in (ROOT / "scenarios", ROOT / "src" / "cellguard" / "scenarios")
                   for p in folder.glob("*.yaml") if not p.name.startswith("release-plan"))


@dataclass(frozen=True)
class SmallArm:
    """The arm's joints with its tool point at a tenth of the size: a decimetre-scale arm (reach about 7 cm)."""

    profile: Profile
    workspace_box: None = None

    @staticmethod
    def tool(q):
        return 0.1 * ARM.tool_point(q)


def test_a_box_in_decimetres_on_the_arm_is_refused_naming_the_axis_and_the_numbers():
    box = [[-4.5, -4.5, 0.05], [4.5, 4.5, 5.5]]  # the arm's own box, written in decimetres
    with pytest.raises(ConfigError) as refused:
        build_guard(ARM, GuardConfig(box=box))
    said = str(refused.value)
    assert re.fullmatch(r"guard\.box: \[\[-4\.5, -4\.5, 0\.05\], \[4\.5, 4\.5, 5\.5\]\] m: z up to 5\.5 m lies "
                        r"4\.8\d m beyond the tool of arm-pick-place \(z from -0\.2\d to 0\.6\d m\), over its reach "
                        r"of 0\.6\d m; the box is in metres, not millimetres or centimetres", said), said


def test_a_ten_metre_box_on_a_decimetre_scale_arm_is_refused():
    with pytest.raises(ConfigError, match=r"^guard\.box: .* m: x down to -10 m lies 9\.9\d m beyond the tool of "
                                          r"arm-pick-place \(x from -0\.05 to 0\.05 m\), over its reach of 0\.06 m;"):
        check_box_reach([[-10.0, -10.0, 0.0], [10.0, 10.0, 10.0]], SmallArm(ARM.profile), SmallArm.tool)


@pytest.mark.parametrize("name", [n for n in cell_names() if getattr(make_cell(n), "workspace_box", None)])
def test_each_cells_own_box_and_a_fence_round_it_pass(name):
    """A box of twice the cell's own (a fence drawn round the cell) guards: the tool comes near its walls."""
    cell = make_cell(name)
    own = np.asarray(cell.workspace_box)
    for box in (own, np.stack([np.where(own[0] < 0, 2 * own[0], own[0]), 2 * own[1]])):
        build_guard(cell, GuardConfig(box=box.tolist()))


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.name)
def test_the_shipped_scenarios_build_their_guards(path):
    scenario = load_scenario(path)
    build_guard(make_cell(scenario.cell), scenario.guard)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2), st.booleans(), st.floats(0.0, 3.0))
def test_a_wall_is_refused_exactly_when_it_lies_over_the_reach_beyond_the_tool(axis, upper, out):
    """Each wall alone moved ``out`` reaches beyond the tool (the others at the arm's own box): refused, naming that
    wall, only past one reach."""
    box = np.asarray(ARM.workspace_box, dtype=np.float64)
    points = np.array([ARM.tool_point(q) for q in np.random.default_rng(0).uniform(
        ARM.profile.q_min, ARM.profile.q_max, (REACH_SAMPLES, ARM.profile.dof))] + list(box))
    lo, hi = points.min(axis=0), points.max(axis=0)
    reach = MARGIN * (hi - lo).max() / 2
    if abs(out - 1.0) < 1e-3:
        return  # on the bound: rounding decides
    box[int(upper), axis] = hi[axis] + out * reach if upper else lo[axis] - out * reach
    if out < 1.0:
        check_box_reach(box.tolist(), ARM, ARM.tool_point)
        return
    with pytest.raises(ConfigError, match=rf"^guard\.box: .* m: {'xyz'[axis]} {('down', 'up')[upper]} to "):
        check_box_reach(box.tolist(), ARM, ARM.tool_point)
