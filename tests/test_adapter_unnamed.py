"""A policy that names none of its actions runs through an action map, never without one.

Taken as the arm's joints in order, in SI, a model answering in degrees ran as radians: exit 0, 240 chunks
refused in one cycle, and nothing said why. Refused, it names the policy and asks for ``?map=FILE``.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
import yaml

pytest.importorskip("onnxruntime")
pytest.importorskip("onnx")

from hostile.scenarios import run_refused, scenario_file  # noqa: E402

from cellguard.errors import ConfigError  # noqa: E402
from cellguard.policy.onnx_export import Mlp, save_mlp_onnx  # noqa: E402
from cellguard.policy.registry import make_policy  # noqa: E402
from cellguard.robot.arm_cell import ArmPickPlace  # noqa: E402

HOME = np.array([0.0, -0.3, 1.9, 1.55, 0.0, 0.025])  # [rad] x5, [m]
ANSWER = np.array([*np.degrees(HOME[:5]), HOME[5] * 1e3])  # the home pose in degrees and mm, every step
MAP = {"robot": "arm-pick-place", "actions": [
    *({"name": f"a{i}", "joint": j, "unit": "deg"} for i, j in
      enumerate(["shoulder_pan", "shoulder_lift", "elbow", "wrist_flex", "wrist_roll"])),
    {"name": "a5", "joint": "gripper", "unit": "mm"}]}


def _refusal(source: str) -> str:
    return (rf"^policy: {re.escape(source)} names none of its 6 actions and carries no action map: give one, "
            rf"\?map=FILE \(which joint each action drives, in which unit\)$")


def _unnamed(path, **metadata) -> str:
    """An ONNX model of six unnamed actions answering ``ANSWER`` whatever it is given, its period stated."""
    mlp = Mlp(inputs=(("time_s", 1),), weights=(np.zeros((1, 4)), np.zeros((4, 6))), biases=(np.zeros(4), np.zeros(6)),
              x_mean=np.zeros(1), x_std=np.ones(1), y_mean=ANSWER, y_std=np.ones(6), horizon=1)
    return str(save_mlp_onnx(mlp, path, {"cellguard.dt_s": "0.05", **metadata}))


def test_an_unnamed_onnx_model_without_a_map_is_refused_naming_it(tmp_path):
    model = _unnamed(tmp_path / "deg.onnx")
    with pytest.raises(ConfigError, match=_refusal(f"onnx:{model}")):
        make_policy(f"onnx:{model}", ArmPickPlace())


def test_a_run_of_it_is_one_line_exit_2_and_leaves_nothing(tmp_path):
    model = _unnamed(tmp_path / "deg.onnx")
    line = run_refused(tmp_path, scenario_file(tmp_path, policy=f"onnx:{model}"))
    assert re.match(_refusal(f"onnx:{model}").replace("^", "^error: ", 1), line), line


def test_an_openpi_server_naming_no_actions_needs_a_map(tmp_path):
    pytest.importorskip("websockets")
    pytest.importorskip("msgpack")
    from hostile.wsserver import serve_bytes

    from cellguard.policy.wire import packb

    with serve_bytes(packb({"action_dim": 6, "dt_s": 0.05})) as uri:
        with pytest.raises(ConfigError, match=_refusal(f"openpi:{uri}")):
            make_policy(f"openpi:{uri}", ArmPickPlace())


@pytest.mark.parametrize("how", ["file", "embedded"])
def test_with_a_map_in_degrees_the_same_model_answers_the_home_pose(tmp_path, how):
    """The map, given or carried by the model, says the unit: the answer is the home pose, not 109 rad."""
    text = yaml.safe_dump(MAP)
    if how == "file":
        (tmp_path / "deg.yaml").write_text(text)
        source = f"onnx:{_unnamed(tmp_path / 'deg.onnx')}?map={tmp_path / 'deg.yaml'}"
    else:
        source = f"onnx:{_unnamed(tmp_path / 'deg.onnx', **{'cellguard.action_map': text})}"
    cell = ArmPickPlace()
    chunk = make_policy(source, cell).infer(cell.observe())
    np.testing.assert_allclose(chunk.actions, HOME[None], atol=1e-5)
