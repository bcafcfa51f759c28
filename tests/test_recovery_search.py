"""retry_grasp's search: attempts may number up to 20, and the pattern has four directions. Attempts 5 to 8
repeated the poses of 1 to 4 (grasps that had already missed); each lap now goes one search step further out."""

from __future__ import annotations

import numpy as np
import pytest

from cellguard.robot.arm_cell import ArmPickPlace
from cellguard.robot.recovery import RECOVERIES


def test_each_lap_of_the_search_pattern_goes_one_step_further_out():
    cell = ArmPickPlace()
    cell.begin_cycle(0)
    home = np.asarray(cell.q_home, dtype=np.float64)
    q = np.append(cell.reach(cell.part_seen(), home[:-1]), home[-1])  # at the part, as where a grasp missed
    grasp = np.asarray(cell.tool_taught(q[:-1]))
    retry = RECOVERIES["retry_grasp"](do="retry_grasp", search_mm=4.0, attempts=8)
    offsets = [np.asarray(cell.tool_taught(retry.plan(cell, q, k, q).contact_q)) - grasp for k in range(1, 9)]
    radii_mm = [float(np.linalg.norm(o[:2])) * 1e3 for o in offsets]
    assert radii_mm == pytest.approx([4.0] * 4 + [8.0] * 4, abs=0.05)
    for k in range(4):  # the same direction, twice as far: never the pose of an attempt before
        np.testing.assert_allclose(offsets[k + 4], 2.0 * offsets[k], atol=5e-5)
