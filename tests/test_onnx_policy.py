"""ONNX adapter: models the tests build with the onnx helper API, run by onnxruntime in the arm cell."""

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

ort = pytest.importorskip("onnxruntime")
pytest.importorskip("onnx")

from foreign_arm import FOREIGN_NAMES, MAP, assert_ran_inside_the_limits, taught_program, to_foreign  # noqa: E402

from cellguard.errors import ConfigError  # noqa: E402
from cellguard.policy.adapter import split_options  # noqa: E402
from cellguard.policy.onnx import OPTIONS  # noqa: E402
from cellguard.policy.onnx_export import Mlp, save_mlp_onnx, trajectory_mlp  # noqa: E402
from cellguard.policy.registry import make_policy  # noqa: E402
from cellguard.robot.arm_cell import ArmPickPlace  # noqa: E402
from cellguard.runtime import Run  # noqa: E402
from cellguard.runtime.startup import StartupRefused  # noqa: E402
from cellguard.scenario import parse_scenario  # noqa: E402


@pytest.fixture(scope="module")
def foreign_model(tmp_path_factory):
    """The taught program as a ReLU network emitting 10-step chunks in the foreign action space."""
    folder = tmp_path_factory.mktemp("onnx")
    times, points = taught_program()
    mlp = trajectory_mlp(times, to_foreign(points), horizon=10, dt_s=0.02)
    model = save_mlp_onnx(mlp, folder / "foreign.onnx", {"cellguard.action_names": ",".join(FOREIGN_NAMES),
                                                          "cellguard.dt_s": "0.02"})
    amap = folder / "foreign.yaml"
    amap.write_text(yaml.safe_dump(MAP))
    return model, amap, mlp


def test_exported_graph_computes_what_the_numpy_network_computes(tmp_path):
    rng = np.random.default_rng(0)
    mlp = Mlp(inputs=(("state", 6), ("time_s", 1)), weights=(rng.normal(size=(7, 16)), rng.normal(size=(16, 12))),
              biases=(rng.normal(size=16), rng.normal(size=12)), x_mean=rng.normal(size=7), x_std=np.full(7, 2.0),
              y_mean=rng.normal(size=12), y_std=np.full(12, 0.5), horizon=2)
    path = save_mlp_onnx(mlp, tmp_path / "m.onnx", {})
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    x = rng.normal(size=(1, 7)).astype(np.float32)
    out = session.run(None, {"state": x[:, :6], "time_s": x[:, 6:]})[0]
    assert out.shape == (1, 2, 6)
    np.testing.assert_allclose(out.reshape(1, -1), mlp.forward(x.astype(np.float64)), rtol=1e-4, atol=1e-4)


def test_onnx_policy_in_a_foreign_action_space_runs_the_arm_cell(foreign_model):
    model, amap, _ = foreign_model
    scenario = parse_scenario({"cell": "arm-pick-place", "seed": 5, "acceptance_cycles": 2, "production_cycles": 0,
                               "policy": f"onnx:{model}?map={amap}"})
    run = Run(scenario)
    outcomes = [run.cycle() for _ in range(2)]
    assert_ran_inside_the_limits(run, outcomes)
    assert len(run.summary()["context"]["policy_sha256"]) == 64


def test_the_same_model_without_its_map_is_refused(foreign_model):
    model, _, _ = foreign_model
    with pytest.raises(ConfigError, match="which are not the joints of 'arm-pick-place'; give an action map"):
        make_policy(f"onnx:{model}", ArmPickPlace())


def test_a_map_that_ignores_the_flipped_elbow_is_refused_before_anything_moves(foreign_model, tmp_path):
    """The mapping matters: drop the elbow's sign and the same model's first target lies where the way to it, under
    the limits, takes the tool over the workspace box's ceiling: the start is refused, nothing moves (it was
    approached, and the cycle failed)."""
    model, _, _ = foreign_model
    wrong = {**MAP, "actions": [{**a, "sign": 1} if a["joint"] == "elbow" else a for a in MAP["actions"]]}
    path = tmp_path / "wrong.yaml"
    path.write_text(yaml.safe_dump(wrong))
    run = Run(parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 0,
                              "policy": f"onnx:{model}?map={path}"}))
    with pytest.raises(StartupRefused, match="the approach to the first target .* leaves the workspace box"):
        run.cycle()
    assert not any(e.kind == "approach_begin" for e in run.events)


def test_bad_models_and_options_are_named(tmp_path, foreign_model):
    cell = ArmPickPlace()
    with pytest.raises(ConfigError, match="no such file"):
        make_policy(f"onnx:{tmp_path / 'none.onnx'}", cell)
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"not a model")
    with pytest.raises(ConfigError, match="not a loadable ONNX model"):
        make_policy(f"onnx:{junk}", cell)
    odd = Mlp(inputs=(("lidar", 3),), weights=(np.ones((3, 6)),), biases=(np.zeros(6),), x_mean=np.zeros(3),
              x_std=np.ones(3), y_mean=np.zeros(6), y_std=np.ones(6), horizon=1)
    path = save_mlp_onnx(odd, tmp_path / "odd.onnx", {})
    with pytest.raises(ConfigError, match="model input 'lidar' cannot be fed"):
        make_policy(f"onnx:{path}", cell)
    with pytest.raises(ConfigError, match="unknown option 'mapp'"):
        make_policy(f"onnx:{foreign_model[0]}?mapp=x", cell)


def test_a_model_whose_state_input_has_another_width_is_refused_at_load(tmp_path):
    """It loaded, and every call failed at run time (inference_failed, then the watchdog's stop)."""
    rng = np.random.default_rng(1)
    mlp = Mlp(inputs=(("state", 3), ("time_s", 1)), weights=(rng.normal(size=(4, 8)), rng.normal(size=(8, 12))),
              biases=(np.zeros(8), np.zeros(12)), x_mean=np.zeros(4), x_std=np.ones(4), y_mean=np.zeros(12),
              y_std=np.ones(12), horizon=2)
    names = ",".join(ArmPickPlace().profile.joint_names)  # named, so that the map is no reason to refuse it
    path = save_mlp_onnx(mlp, tmp_path / "narrow.onnx", {"cellguard.action_names": names})
    with pytest.raises(ConfigError, match=r"model input 'state' has shape \[1, 3\]; the cell feeds it \(1, 6\)"):
        make_policy(f"onnx:{path}?dt=0.02", ArmPickPlace())


def test_a_repeated_option_is_refused_naming_it(foreign_model):
    """``?dt=0.02&dt=0.5`` ran with the last value, silently."""
    with pytest.raises(ConfigError, match=r"policy: onnx: option 'dt' is given twice \('0.02' and '0.5'\)"):
        make_policy(f"onnx:{foreign_model[0]}?dt=0.02&dt=0.5", ArmPickPlace())


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(["map", "dt"]), st.text(alphabet="ab0.1/ ", max_size=5)), max_size=4))
def test_options_are_taken_once_each_or_refused(pairs):
    query = "&".join(f"{k}={v}" for k, v in pairs)
    keys = [k for k, _ in pairs]
    if len(set(keys)) < len(keys):
        with pytest.raises(ConfigError, match="is given twice"):
            split_options(f"m.onnx?{query}", OPTIONS, "onnx")
    else:
        assert split_options(f"m.onnx?{query}", OPTIONS, "onnx") == ("m.onnx", dict(pairs))


def test_a_model_whose_output_declares_horizon_zero_is_refused_at_load(tmp_path):
    """It loaded, and the guard rejected every (empty) chunk at run time."""
    from onnx import TensorProto, helper, numpy_helper, save

    out = helper.make_tensor_value_info("actions", TensorProto.FLOAT, [1, 0, 6])
    graph = helper.make_graph(
        [helper.make_node("Mul", ["time_s", "zero"], ["t0"]), helper.make_node("Add", ["empty", "t0"], ["actions"])],
        "h0", [helper.make_tensor_value_info("time_s", TensorProto.FLOAT, [1, 1])], [out],
        [numpy_helper.from_array(np.zeros((1, 0, 6), np.float32), "empty"),
         numpy_helper.from_array(np.zeros((1, 1), np.float32), "zero")])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    save(model, tmp_path / "h0.onnx")
    with pytest.raises(ConfigError, match=r"first output 'actions' declares shape \[1, 0, 6\]"):
        make_policy(f"onnx:{tmp_path / 'h0.onnx'}", ArmPickPlace())
