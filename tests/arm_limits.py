"""Shared by the guard's limit tests: the arm's limits, its soft limits' margin and the tolerances the tests hold
the envelope's setpoints to (finite differences of a 1 ms servo stream)."""

from __future__ import annotations

from cellguard.control.config import GuardConfig
from cellguard.robot.registry import make_cell

PROFILE = make_cell("arm-pick-place").profile
DT = 1e-3
LO, HI = PROFILE.q_min, PROFILE.q_max
V, A, J = PROFILE.array("velocity"), PROFILE.array("acceleration"), PROFILE.array("jerk")
MARGIN = GuardConfig().soft_margin * (HI - LO)
MID = 0.5 * (LO + HI)
V_TOL, A_TOL, J_TOL = 2e-3, 2e-2, 0.2
