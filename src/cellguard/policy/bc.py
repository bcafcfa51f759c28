"""Behaviour cloning of the scripted arm program into a small MLP, on the CPU, in numpy.

Demonstrations are recorded in the simulated cell through the whole tick path: each chunk the
scripted policy emits is a label for what it saw (time since the cycle began, the camera's
reading of the part). A tanh MLP learns ``(time_s, part_in_camera) -> next H joint targets``
with Adam on the squared error of normalised targets, and is saved as ONNX with its action
names (the arm's joints, SI) so that ``policy: onnx:FILE`` runs it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cellguard.policy.chunk import ActionChunk
from cellguard.policy.onnx_export import Mlp, save_mlp_onnx
from cellguard.robot.state import Observation

INPUTS = (("time_s", 1), ("part_in_camera", 3))
TAIL_S, TAIL_SAMPLES = 4.0, 40  # [s] how long after each demonstration's end home is taught, and how densely


@dataclass(frozen=True)
class TrainingReport:
    """What ``train_demo_policy`` did, for the command's output and the model's metadata."""

    path: str
    cycles: int
    samples: int
    steps: int
    final_loss: float  # mean squared error of normalised targets
    max_error_mrad: float  # worst joint error on the training set after training
    seconds: float


class _Recorder:
    """Wraps a policy; keeps (inputs, first ``horizon`` steps) of every chunk it answers."""

    def __init__(self, policy, horizon: int):
        self.policy, self.horizon = policy, horizon
        self.source = policy.source
        self.x: list[np.ndarray] = []
        self.y: list[np.ndarray] = []
        self._t0: int | None = None

    def reset(self) -> None:
        self._t0 = None
        self.policy.reset()

    def content_hash(self) -> str:
        return self.policy.content_hash()

    def infer(self, observation: Observation) -> ActionChunk:
        if self._t0 is None:
            self._t0 = observation.t_ns
        chunk = self.policy.infer(observation)
        t = (observation.t_ns - self._t0) * 1e-9
        self.x.append(np.concatenate([[t], observation.measurements["part_in_camera"]]))
        self.y.append(np.asarray(chunk.actions[: self.horizon]).reshape(-1))
        return chunk


def collect_demonstrations(cycles: int, seed: int, horizon: int) -> tuple[np.ndarray, np.ndarray, float, tuple]:
    """Run the scripted program for ``cycles``: inputs (N, 4), targets (N, horizon*dof), dt [s], joint names."""
    from cellguard.runner import Run
    from cellguard.scenario import parse_scenario

    run = Run(parse_scenario({"cell": "arm-pick-place", "seed": seed, "policy": "scripted",
                              "acceptance_cycles": cycles, "production_cycles": 0}))
    recorder = _Recorder(run.policy, horizon)
    run.policy = recorder
    for _ in range(cycles):
        run.cycle()
    x, y = np.array(recorder.x), np.array(recorder.y)
    # After the program ends the arm holds home: teach that for later times too, so a cycle that
    # runs a little long still comes to rest at home (where the cell declares the cycle over).
    ends = np.flatnonzero(np.diff(x[:, 0], append=-1.0) < 0)
    tail_x = np.repeat(x[ends], TAIL_SAMPLES, axis=0)
    tail_x[:, 0] += np.tile(np.linspace(0.05, TAIL_S, TAIL_SAMPLES), len(ends))
    x, y = np.vstack([x, tail_x]), np.vstack([y, np.repeat(y[ends], TAIL_SAMPLES, axis=0)])
    return x, y, recorder.policy.dt_ns * 1e-9, run.cell.profile.joint_names


def train_mlp(x: np.ndarray, y: np.ndarray, horizon: int, hidden: int, steps: int, seed: int) -> tuple[Mlp, float]:
    """Adam on mean squared error of normalised targets; returns the MLP and the final loss."""
    rng = np.random.default_rng(seed)
    x_mean, x_std = x.mean(0), x.std(0) + 1e-6
    y_mean, y_std = y.mean(0), y.std(0) + 1e-6
    xn, yn = (x - x_mean) / x_std, (y - y_mean) / y_std
    sizes = [x.shape[1], hidden, hidden, y.shape[1]]
    params = []
    for a, b in zip(sizes[:-1], sizes[1:]):
        params += [rng.normal(0.0, np.sqrt(1.0 / a), (a, b)), np.zeros(b)]
    m = [np.zeros_like(p) for p in params]
    v = [np.zeros_like(p) for p in params]
    batch, loss = min(256, len(x)), np.inf
    for step in range(1, steps + 1):
        lr = 3e-3 * 0.5 * (1.0 + np.cos(np.pi * step / steps)) + 1e-5  # cosine decay
        idx = rng.integers(0, len(x), batch)
        grads, loss = _gradients(params, xn[idx], yn[idx])
        for p, g, mi, vi in zip(params, grads, m, v):
            mi *= 0.9
            mi += 0.1 * g
            vi *= 0.999
            vi += 0.001 * g * g
            p -= lr * (mi / (1 - 0.9**step)) / (np.sqrt(vi / (1 - 0.999**step)) + 1e-8)
    mlp = Mlp(inputs=INPUTS, weights=tuple(params[0::2]), biases=tuple(params[1::2]), x_mean=x_mean, x_std=x_std,
              y_mean=y_mean, y_std=y_std, horizon=horizon)
    return mlp, float(loss)


def _gradients(params: list[np.ndarray], x: np.ndarray, y: np.ndarray) -> tuple[list[np.ndarray], float]:
    w1, b1, w2, b2, w3, b3 = params
    h1 = np.tanh(x @ w1 + b1)
    h2 = np.tanh(h1 @ w2 + b2)
    err = h2 @ w3 + b3 - y
    loss = float(np.mean(err**2))
    d3 = 2.0 * err / err.size
    d2 = (d3 @ w3.T) * (1.0 - h2**2)
    d1 = (d2 @ w2.T) * (1.0 - h1**2)
    return [x.T @ d1, d1.sum(0), h1.T @ d2, d2.sum(0), h2.T @ d3, d3.sum(0)], loss


def train_demo_policy(out: Path, cycles: int = 30, steps: int = 6000, hidden: int = 256, horizon: int = 10,
                      seed: int = 0) -> TrainingReport:
    """Record ``cycles`` scripted demonstrations, clone them, and save ``out`` (ONNX)."""
    began = time.perf_counter()
    x, y, dt, joints = collect_demonstrations(cycles, seed, horizon)
    mlp, loss = train_mlp(x, y, horizon, hidden, steps, seed)
    worst = float(np.abs(mlp.forward(x) - y).max())
    path = save_mlp_onnx(mlp, Path(out), {
        "cellguard.action_names": ",".join(joints),
        "cellguard.dt_s": repr(dt),
        "cellguard.trained_on": f"{cycles} scripted arm-pick-place cycles, seed {seed}",
    })
    return TrainingReport(str(path), cycles, len(x), steps, loss, worst * 1e3, time.perf_counter() - began)
