"""A retreat from a command still moving (a time cycle that ended mid-motion) brakes it to rest first and checks the
way home against the box from there: checked before the brake, the moving command held its last setpoint the 15 to
100 ms the check took on wall time, a dead stop at speed."""

from __future__ import annotations

import numpy as np

from cellguard.robot.registry import make_cell
from cellguard.runtime import Run
from cellguard.runtime.transitions import Transition
from cellguard.scenario import parse_scenario


def test_the_way_home_is_checked_with_the_command_at_rest(tmp_path, monkeypatch):
    home = np.array(make_cell("arm-pick-place").read().q, dtype=np.float64)
    t = np.arange(0.0, 3.0, 0.1)  # chunks of 25 steps of 20 ms turning the base at 0.5 rad/s, past the cycle's end
    actions = np.array([[home + np.array([0.5 * (s + k * 0.02), 0, 0, 0, 0, 0]) for k in range(1, 26)] for s in t])
    np.savez(tmp_path / "turn.npz", t=t, actions=actions, dt=np.float64(0.02))
    checked = []
    leaves_box = Transition.leaves_box

    def watched(plan, *args):
        checked.append(float(np.abs(plan.state_at(0.0)[1]).max()))  # the command's speed when its way is checked
        return leaves_box(plan, *args)

    monkeypatch.setattr(Transition, "leaves_box", watched)
    run = Run(parse_scenario({"cell": "arm-pick-place", "policy": f"replay:{tmp_path / 'turn.npz'}",
                              "acceptance_cycles": 1, "production_cycles": 0,
                              "cycle": {"source": "time", "seconds": 1.0}}))
    try:
        run.run_cycles()
    finally:
        run.close()
    kinds = [e.kind for e in run.events]
    assert "retreat_done" in kinds and run.stopped is None
    assert checked and max(checked) < 1e-6  # every check found the command at rest
