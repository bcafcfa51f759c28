"""ONNX adapter: what a model declares is checked at load; what it returns is checked per call.

Constant models built with the onnx helper API: ``actions = chunk + 0 * sum(state)``, with the
state input of a chosen element type and the output declared in a chosen shape.
"""

import hashlib
import re
import tracemalloc

import numpy as np
import pytest

pytest.importorskip("onnxruntime")
onnx = pytest.importorskip("onnx")

from onnx import TensorProto, helper, numpy_helper  # noqa: E402

from cellguard.errors import ConfigError  # noqa: E402
from cellguard.policy.adapter import InferenceError  # noqa: E402
from cellguard.policy.chunk import MAX_HORIZON  # noqa: E402
from cellguard.policy.onnx import OnnxBackend  # noqa: E402
from cellguard.policy.registry import make_policy  # noqa: E402
from cellguard.robot.arm_cell import ArmPickPlace  # noqa: E402

HOME = np.array([0.0, -0.3, 1.9, 1.55, 0.0, 0.025])
NAMES = "shoulder_pan,shoulder_lift,elbow,wrist_flex,wrist_roll,gripper"


def _save(graph, path):
    """``graph`` as an opset-17 model naming the arm's six actions and its step period, saved at ``path``."""
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    helper.set_model_props(model, {"cellguard.action_names": NAMES, "cellguard.dt_s": "0.02"})
    onnx.save(model, path)
    return path


def constant_model(path, value: np.ndarray, declared: list, state_type=TensorProto.FLOAT,
                   output_type=TensorProto.FLOAT, state_shape=(1, 6)):
    """A model answering ``value`` whatever its state input (of ``state_type``, ``state_shape``), its output
    declared ``declared`` of ``output_type``."""
    nodes = [helper.make_node("Cast", ["state"], ["s32"], to=TensorProto.FLOAT),
             helper.make_node("ReduceSum", ["s32"], ["sum"], keepdims=0),
             helper.make_node("Mul", ["sum", "zero"], ["z"]), helper.make_node("Add", ["value", "z"], ["sum32"]),
             helper.make_node("Cast", ["sum32"], ["actions"], to=output_type)]
    graph = helper.make_graph(nodes, "constant", [helper.make_tensor_value_info("state", state_type, [*state_shape])],
                              [helper.make_tensor_value_info("actions", output_type, declared)],
                              [numpy_helper.from_array(value.astype(np.float32), "value"),
                               numpy_helper.from_array(np.zeros((), np.float32), "zero")])
    return _save(graph, path)


@pytest.fixture(scope="module")
def cell():
    return ArmPickPlace()


@pytest.mark.parametrize("state_type", [TensorProto.FLOAT, TensorProto.DOUBLE, TensorProto.FLOAT16])
def test_a_float_input_is_fed_in_the_type_it_declares(tmp_path, cell, state_type):
    """A double input loaded, then every call failed (a float32 array fed to it): 240 inference_failed."""
    path = constant_model(tmp_path / "m.onnx", np.tile(HOME, (1, 10, 1)), [1, 10, 6], state_type)
    policy = make_policy(f"onnx:{path}", cell)
    chunk = policy.infer(cell.observe())
    np.testing.assert_allclose(chunk.actions, np.tile(HOME, (10, 1)), atol=1e-6)
    assert policy.content_hash() == hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.parametrize("state_type, kind", [(TensorProto.INT64, "tensor(int64)"), (TensorProto.BOOL, "tensor(bool)"),
                                              (TensorProto.STRING, "tensor(string)")])
def test_an_input_the_float_observations_cannot_be_fed_as_is_refused_at_load(tmp_path, cell, state_type, kind):
    path = constant_model(tmp_path / "m.onnx", np.tile(HOME, (1, 10, 1)), [1, 10, 6], state_type)
    why = rf"model input 'state' is {re.escape(kind)}; the cell's observations are floats, fed as tensor\(float16\), "
    with pytest.raises(ConfigError, match=why + r"tensor\(float\), tensor\(double\)"):
        make_policy(f"onnx:{path}", cell)


@pytest.mark.parametrize("value, declared", [(np.tile(HOME, (1, 10, 1)), [1, 10, 6]), (np.tile(HOME, (10, 1)), [10, 6]),
                                             (HOME[None], [1, 6])])
def test_the_three_chunk_shapes_give_the_chunk(tmp_path, cell, value, declared):
    policy = make_policy(f"onnx:{constant_model(tmp_path / 'm.onnx', value, declared)}", cell)
    np.testing.assert_allclose(policy.infer(cell.observe()).actions, value.reshape(-1, 6), atol=1e-6)


@pytest.mark.parametrize("declared", [[2, 10, 6], [1, 2, 10, 6], [6]])
def test_an_output_declared_in_another_shape_is_refused_at_load(tmp_path, cell, declared):
    """(2, 10, 6) and (1, 2, 10, 6) were flattened into one (20, 6) chunk: two samples played one after the other."""
    path = constant_model(tmp_path / "m.onnx", np.zeros(declared), declared)
    why = rf"first output 'actions' declares shape {re.escape(str(declared))}; "
    with pytest.raises(ConfigError, match=why + r"a chunk is \(1, H, 6\), \(H, 6\) or \(1, 6\)"):
        make_policy(f"onnx:{path}", cell)


def batch_model(path, value: np.ndarray):
    """``value`` reshaped at run time to its own shape (through the state input), so no tool infers it: the output
    stays declared (B, H, 6)."""
    nodes = [helper.make_node("ReduceSum", ["state"], ["sum"], keepdims=0),
             helper.make_node("Mul", ["sum", "zero"], ["z"]),
             helper.make_node("Cast", ["z"], ["zi"], to=TensorProto.INT64),
             helper.make_node("Add", ["shape", "zi"], ["runtime_shape"]),
             helper.make_node("Reshape", ["flat", "runtime_shape"], ["actions"])]
    graph = helper.make_graph(nodes, "batch", [helper.make_tensor_value_info("state", TensorProto.FLOAT, [1, 6])],
                              [helper.make_tensor_value_info("actions", TensorProto.FLOAT, ["B", "H", 6])],
                              [numpy_helper.from_array(value.astype(np.float32).ravel(), "flat"),
                               numpy_helper.from_array(np.array(value.shape, np.int64), "shape"),
                               numpy_helper.from_array(np.zeros((), np.float32), "zero")])
    return _save(graph, path)


def test_an_undeclared_batch_of_chunks_is_refused_at_the_call_naming_its_shape(tmp_path, cell):
    two = np.stack([np.tile(HOME, (10, 1)), np.tile(HOME + 0.05, (10, 1))])
    policy = make_policy(f"onnx:{batch_model(tmp_path / 'm.onnx', two)}", cell)
    with pytest.raises(InferenceError, match=r"first output has shape \(2, 10, 6\); a chunk is \(1, H, 6\)"):
        policy.infer(cell.observe())


def test_a_file_over_protobufs_limit_is_refused_by_its_size_unread(tmp_path):
    """A 3 GB file was read whole (3.3 GB resident) to hash it, then refused as not a model."""
    huge = tmp_path / "huge.onnx"
    with huge.open("wb") as file:
        file.truncate((2 << 30) + 1)  # sparse: no disk used
    with pytest.raises(ConfigError, match=r"2147483649 bytes; protobuf reads no model file of 2 GiB or more"):
        OnnxBackend(huge, ())


def test_the_file_is_hashed_in_pieces(tmp_path):
    junk = tmp_path / "junk.onnx"
    with junk.open("wb") as file:
        file.truncate(64 << 20)
    tracemalloc.start()
    try:
        with pytest.raises(ConfigError, match="not a loadable ONNX model"):
            OnnxBackend(junk, ())
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 8 << 20  # [bytes] of Python memory for a 64 MiB file


def test_a_model_with_its_weights_as_external_data_still_loads(tmp_path, cell):
    """The size limit is the model file's: weights kept beside it (how a model over 2 GiB ships) are not counted."""
    path = constant_model(tmp_path / "m.onnx", np.tile(HOME, (1, 10, 1)), [1, 10, 6])
    model = onnx.load(path)
    onnx.save(model, path, save_as_external_data=True, all_tensors_to_one_file=True, location="m.weights",
              size_threshold=0)
    assert (tmp_path / "m.weights").stat().st_size > 0
    policy = make_policy(f"onnx:{path}", cell)
    np.testing.assert_allclose(policy.infer(cell.observe()).actions, np.tile(HOME, (10, 1)), atol=1e-6)


@pytest.mark.parametrize("output_type, kind", [(TensorProto.INT64, "tensor(int64)"), (TensorProto.BOOL, "tensor(bool)"),
                                               (TensorProto.STRING, "tensor(string)")])
def test_a_chunk_of_other_than_floats_is_refused_at_load(tmp_path, cell, output_type, kind):
    """An int64 chunk loaded and was truncated (the arm driven to a wrong pose); bool or string failed every call."""
    path = constant_model(tmp_path / "m.onnx", np.tile(HOME, (1, 10, 1)), [1, 10, 6], output_type=output_type)
    with pytest.raises(ConfigError, match=rf"first output 'actions' is {re.escape(kind)}; a chunk is joint targets, "
                                          r"floats: tensor\(float16\), tensor\(float\), tensor\(double\)"):
        make_policy(f"onnx:{path}", cell)


@pytest.mark.parametrize("state_shape", [(6,), (2, 6), (1, 1, 6), ()])
def test_an_input_of_another_rank_or_batch_than_fed_is_refused_at_load(tmp_path, cell, state_shape):
    """A state input (6,) or (2, 6) loaded, then every call failed: 240 inference_failed and a protective stop."""
    path = constant_model(tmp_path / "m.onnx", np.tile(HOME, (1, 10, 1)), [1, 10, 6], state_shape=state_shape)
    with pytest.raises(ConfigError, match=rf"model input 'state' has shape {re.escape(str(list(state_shape)))}; "
                                          r"the cell feeds it \(1, 6\)"):
        make_policy(f"onnx:{path}", cell)


def test_a_state_input_with_a_free_batch_dimension_loads(tmp_path, cell):
    path = constant_model(tmp_path / "m.onnx", np.tile(HOME, (1, 10, 1)), [1, 10, 6], state_shape=("B", 6))
    np.testing.assert_allclose(make_policy(f"onnx:{path}", cell).infer(cell.observe()).actions,
                               np.tile(HOME, (10, 1)), atol=1e-6)


def _external(tmp_path, location="m.weights"):
    """The constant model with its weights in external data named ``location`` (relative to its folder)."""
    path = constant_model(tmp_path / "m.onnx", np.tile(HOME, (1, 10, 1)), [1, 10, 6])
    onnx.save(onnx.load(path), path, save_as_external_data=True, all_tensors_to_one_file=True, location=location,
              size_threshold=0)
    return path


def test_new_external_weights_beside_an_unchanged_model_file_are_a_new_hash(tmp_path, cell):
    """A release froze the .onnx file's hash only: weights swapped after create passed promote, and drove the arm."""
    path = _external(tmp_path)
    before = make_policy(f"onnx:{path}", cell).content_hash()
    weights = np.fromfile(tmp_path / "m.weights", dtype=np.float32)
    weights[:6] += 0.5
    weights.tofile(tmp_path / "m.weights")
    after = make_policy(f"onnx:{path}", cell)
    assert not np.allclose(after.infer(cell.observe()).actions, np.tile(HOME, (10, 1)), atol=1e-3)
    assert after.content_hash() != before
    assert before != hashlib.sha256(path.read_bytes()).hexdigest()  # the weights are in it


@pytest.mark.parametrize("location", ["../outside.weights", "link.weights", "missing.weights"])
def test_external_data_out_of_the_models_folder_or_missing_is_refused_naming_it(tmp_path, cell, location):
    """Only files beside the model are hashed; one elsewhere (a path up, a link out) is refused, not read."""
    folder = tmp_path / "model"
    folder.mkdir()
    path = _external(folder)
    model = onnx.load(path, load_external_data=False)
    for tensor in model.graph.initializer:
        for entry in tensor.external_data:
            if entry.key == "location":
                entry.value = location
    onnx.save(model, path)
    (tmp_path / "outside.weights").write_bytes((folder / "m.weights").read_bytes())
    (folder / "link.weights").symlink_to(tmp_path / "outside.weights")
    with pytest.raises(ConfigError, match=rf"external data '{re.escape(location)}' is not a file in the model's "):
        make_policy(f"onnx:{path}", cell)


def test_a_model_linked_into_a_hugging_face_cache_loads_with_its_external_weights(tmp_path, cell):
    """snapshots/REV/{m.onnx, m.weights} link to blobs named by their hashes: the weights resolved out of
    snapshots/REV and were refused, though onnxruntime reads them (from the folder the model's file lies in)."""
    blobs, snapshot = tmp_path / "blobs", tmp_path / "snapshots" / "rev"
    blobs.mkdir()
    snapshot.mkdir(parents=True)
    _external(blobs)
    for name in ("m.onnx", "m.weights"):
        blob = hashlib.sha256((blobs / name).read_bytes()).hexdigest()
        (blobs / name).rename(blobs / blob)
        (snapshot / name).symlink_to(f"../../blobs/{blob}")
    policy = make_policy(f"onnx:{snapshot / 'm.onnx'}", cell)
    assert np.allclose(policy.infer(cell.observe()).actions, np.tile(HOME, (10, 1)), atol=1e-3)


@pytest.mark.parametrize("declared", [[1, MAX_HORIZON + 1, 6], [MAX_HORIZON + 1, 6]])
def test_a_chunk_longer_than_the_guard_takes_is_refused_at_load(tmp_path, cell, declared):
    """A fixed horizon of 1001 loaded, then the guard rejected every chunk (chunk_rejected, exit 0)."""
    path = constant_model(tmp_path / "m.onnx", np.tile(HOME, (1, MAX_HORIZON + 1, 1)).reshape(declared), declared)
    with pytest.raises(ConfigError, match=rf"{MAX_HORIZON + 1} steps; the guard takes a chunk of at most {MAX_HORIZON}"):
        make_policy(f"onnx:{path}", cell)
    ok = constant_model(tmp_path / "ok.onnx", np.tile(HOME, (1, MAX_HORIZON, 1)), [1, MAX_HORIZON, 6])
    assert make_policy(f"onnx:{ok}", cell).infer(cell.observe()).horizon == MAX_HORIZON
