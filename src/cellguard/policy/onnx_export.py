"""Write a small MLP policy as an ONNX file with the onnx helper API (no torch needed).

The graph concatenates its named inputs, normalises them, runs tanh hidden layers and
un-normalises the output into a chunk (1, H, A). The tests build their models with it, and
``cellguard train-demo-policy`` saves the behaviour-cloned policy with it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cellguard.errors import ConfigError
from cellguard.output import write_output


@dataclass(frozen=True)
class Mlp:
    """Weights of ``y = W_n(...act(W_1 ((x - x_mean) / x_std) + b_1)...) + b_n``, then ``y * y_std + y_mean``.

    ``inputs`` are (name, width) in concatenation order; the output is reshaped to (1, horizon, A).
    """

    inputs: tuple[tuple[str, int], ...]
    weights: tuple[np.ndarray, ...]  # each (n_in, n_out)
    biases: tuple[np.ndarray, ...]  # each (n_out,)
    x_mean: np.ndarray
    x_std: np.ndarray
    y_mean: np.ndarray
    y_std: np.ndarray
    horizon: int
    activation: str = "tanh"  # or "relu"

    def forward(self, x: np.ndarray) -> np.ndarray:
        """The same function in numpy: x (N, n_in) -> (N, horizon * A)."""
        h = (x - self.x_mean) / self.x_std
        for i, (w, b) in enumerate(zip(self.weights, self.biases)):
            h = h @ w + b
            if i < len(self.weights) - 1:
                h = np.tanh(h) if self.activation == "tanh" else np.maximum(h, 0.0)
        return h * self.y_std + self.y_mean


def save_mlp_onnx(mlp: Mlp, path: Path, metadata: dict[str, str], replace: bool = True) -> Path:
    """Write ``mlp`` to ``path`` with ``metadata`` as model properties (``cellguard.*``); a file at ``path``
    is replaced only if ``replace``."""
    try:
        import onnx
        from onnx import TensorProto, helper, numpy_helper
    except ImportError:  # pragma: no cover - depends on the environment
        raise ConfigError("saving an ONNX policy needs the onnx package: pip install 'cellguard[onnx]'") from None
    f32 = np.float32
    out_dim = mlp.weights[-1].shape[1]
    if mlp.activation not in ("tanh", "relu"):
        raise ConfigError(f"mlp: activation must be tanh or relu, got {mlp.activation!r}")
    if out_dim % mlp.horizon:
        raise ConfigError(f"mlp: output width {out_dim} is not a multiple of horizon {mlp.horizon}")
    inits = [numpy_helper.from_array(np.asarray(a, f32), name) for name, a in (
        ("x_mean", mlp.x_mean), ("x_std", mlp.x_std), ("y_mean", mlp.y_mean), ("y_std", mlp.y_std))]
    inits.append(numpy_helper.from_array(np.array([1, mlp.horizon, out_dim // mlp.horizon], np.int64), "out_shape"))
    nodes = [helper.make_node("Concat", [n for n, _ in mlp.inputs], ["x"], axis=1),
             helper.make_node("Sub", ["x", "x_mean"], ["xc"]),
             helper.make_node("Div", ["xc", "x_std"], ["h0"])]
    h = "h0"
    for i, (w, b) in enumerate(zip(mlp.weights, mlp.biases)):
        inits += [numpy_helper.from_array(np.asarray(w, f32), f"w{i}"), numpy_helper.from_array(np.asarray(b, f32), f"b{i}")]
        nodes += [helper.make_node("MatMul", [h, f"w{i}"], [f"m{i}"]), helper.make_node("Add", [f"m{i}", f"b{i}"], [f"a{i}"])]
        h = f"a{i}"
        if i < len(mlp.weights) - 1:
            nodes.append(helper.make_node("Tanh" if mlp.activation == "tanh" else "Relu", [h], [f"t{i}"]))
            h = f"t{i}"
    nodes += [helper.make_node("Mul", [h, "y_std"], ["ys"]), helper.make_node("Add", ["ys", "y_mean"], ["y"]),
              helper.make_node("Reshape", ["y", "out_shape"], ["actions"])]
    graph = helper.make_graph(
        nodes, "cellguard_mlp_policy",
        [helper.make_tensor_value_info(n, TensorProto.FLOAT, [1, w]) for n, w in mlp.inputs],
        [helper.make_tensor_value_info("actions", TensorProto.FLOAT, [1, mlp.horizon, out_dim // mlp.horizon])],
        inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], producer_name="cellguard")
    model.ir_version = 8
    helper.set_model_props(model, metadata)
    onnx.checker.check_model(model)
    return write_output(Path(path), model.SerializeToString(), "ONNX model", replace)


def trajectory_mlp(times: np.ndarray, points: np.ndarray, horizon: int, dt_s: float) -> Mlp:
    """An exact ReLU network of a piecewise-linear trajectory: ``time_s`` -> the next ``horizon`` points.

    ``times`` (N,) [s] increasing, ``points`` (N, A); before ``times[0]`` the first point, after
    the last the last point. One hidden unit per (step, knot): ``relu(t + (i+1) dt - t_k)``.
    This bakes a taught program into a model file, to exercise an adapter end to end.
    """
    times, points = np.asarray(times, np.float64), np.asarray(points, np.float64)
    slopes = np.diff(points, axis=0) / np.diff(times)[:, None]  # (N-1, A)
    kinks = np.diff(np.vstack([np.zeros((1, points.shape[1])), slopes, np.zeros((1, points.shape[1]))]), axis=0)
    n_knots, dim = len(times), points.shape[1]
    offsets = (np.arange(horizon) + 1) * dt_s
    w1 = np.ones((1, horizon * n_knots))
    b1 = (offsets[:, None] - times[None, :]).reshape(-1)
    w2 = np.zeros((horizon * n_knots, horizon * dim))
    for i in range(horizon):
        w2[i * n_knots:(i + 1) * n_knots, i * dim:(i + 1) * dim] = kinks
    b2 = np.tile(points[0], horizon)
    one = np.ones(1)
    return Mlp(inputs=(("time_s", 1),), weights=(w1, w2), biases=(b1, b2), x_mean=np.zeros(1), x_std=one,
               y_mean=np.zeros(horizon * dim), y_std=np.ones(horizon * dim), horizon=horizon, activation="relu")
