"""A scenario's ``guard.soft_margin`` bounds the IK of a policy whose actions are end-effector poses.

The IK kept the default margin (2 % of each joint's range) whatever the guard's: under ``soft_margin: 0.1`` a target
between the two soft limits was "reached" by the IK and the guard then held the joint at its own soft limit, so the
tool missed with no failure named.
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml

pytest.importorskip("onnxruntime")
pytest.importorskip("onnx")
pytest.importorskip("mink")

from cellguard.policy.adapter import InferenceError  # noqa: E402
from cellguard.policy.onnx_export import Mlp, save_mlp_onnx  # noqa: E402
from cellguard.policy.registry import make_policy  # noqa: E402
from cellguard.robot.arm_cell import ArmPickPlace  # noqa: E402
from cellguard.scenario import parse_scenario  # noqa: E402
from test_ik_soft_limits import XYZ_MAP  # noqa: E402



@pytest.fixture(scope="module")
def spec(tmp_path_factory):
    """An ONNX policy of three end-effector actions (x y z) with its action map, as a scenario's ``policy:``."""
    folder = tmp_path_factory.mktemp("ee")
    mlp = Mlp(inputs=(("time_s", 1),), weights=(np.zeros((1, 3)),), biases=(np.zeros(3),), x_mean=np.zeros(1),
              x_std=np.ones(1), y_mean=np.zeros(3), y_std=np.ones(3), horizon=1)
    model = save_mlp_onnx(mlp, folder / "ee.onnx", {"cellguard.action_names": "x,y,z", "cellguard.dt_s": "0.02"})
    (folder / "ee.yaml").write_text(yaml.safe_dump(XYZ_MAP))
    return f"onnx:{model}?map={folder / 'ee.yaml'}"


def _beyond_wide_margin(policy, cell, margin: float):
    """From the pan 0.05 rad inside the soft limit of ``margin``, a target 0.05 rad past it (inside the default's):
    the joints the IK gives, or its refusal."""
    pan = cell.profile.index("shoulder_pan")
    hi = cell.profile.soft_limits(margin)[1][pan]
    start = cell.q_home.copy()
    start[pan] = hi - 0.05
    home = policy.solver.pose(cell.q_home)[:3]
    radius, angle = np.hypot(home[0], home[1]), hi + 0.05
    target = np.array([[radius * np.cos(angle), radius * np.sin(angle), home[2]]])
    return policy.action_map.to_robot(target, start, policy.solver), pan, hi


def test_a_scenarios_soft_margin_bounds_the_ik_of_its_policy(spec):
    cell = ArmPickPlace()
    margin = parse_scenario({"cell": cell.name, "policy": spec, "guard": {"soft_margin": 0.1}}).guard.soft_margin
    assert cell.profile.soft_limits(margin)[1][0] < cell.profile.soft_limits()[1][0] - 0.3  # [rad] apart
    policy = make_policy(spec, cell, soft_margin=margin)
    with pytest.raises(InferenceError, match=r"held at the guard's soft limit: shoulder_pan at 2\.000 rad"):
        _beyond_wide_margin(policy, cell, margin)


def test_at_the_default_margin_the_same_target_is_reached(spec):
    """The same target, with the guard's default margin: reached, past the wider margin's soft limit."""
    cell = ArmPickPlace()
    q, pan, hi = _beyond_wide_margin(make_policy(spec, cell), cell, 0.1)
    assert q[0, pan] > hi + 0.04


@pytest.mark.parametrize("inference", ["thread", "process"])
def test_a_runs_policy_has_its_scenarios_margin(spec, inference):
    """As the run builds it, in the loop's process or the inference process."""
    from cellguard.runtime import Run
    from cellguard.runtime.build import _policy_again

    scenario = parse_scenario({"cell": "arm-pick-place", "policy": f"{spec}&dt=0.02", "guard": {"soft_margin": 0.1},
                               "acceptance_cycles": 1, "production_cycles": 0, "realtime": {"inference": inference}})
    run = Run(scenario)
    try:
        policy = run.policy if inference == "thread" else _policy_again(run)()
        with pytest.raises(InferenceError, match=r"held at the guard's soft limit: shoulder_pan at 2\.000 rad"):
            _beyond_wide_margin(policy, run.cell, 0.1)
    finally:
        run.close()
