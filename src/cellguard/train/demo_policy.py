"""Behaviour cloning of the scripted arm program into a small network, on the CPU, in numpy.

Demonstrations are recorded in the simulated cell through the whole tick path: each chunk the
scripted policy emits is a label for what it saw (time since the cycle began, the camera's
reading of the part). The expert is also asked at a few times between requests (the same
observation, its clock shifted), so that the clone is taught between the grid points the
runner happens to use. The network is one tanh layer, ``(time_s, part_in_camera) -> next H
joint targets``: a fixed basis of steps in time (one every ``BASIS_SPACING_S``, so each segment
of the program can be told apart) plus random features of every input, and an output layer fit
by ridge least squares, which is exact and takes a second where gradient descent on a plain MLP
took minutes and still missed the grasp by centimetres. It is saved as ONNX with its action
names (the arm's joints, SI) so that ``policy: onnx:FILE`` runs it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from cellguard.policy.chunk import ActionChunk
from cellguard.policy.onnx_export import Mlp, save_mlp_onnx
from cellguard.robot.state import Observation

INPUTS = (("time_s", 1), ("part_in_camera", 3))
TAIL_S, TAIL_SAMPLES = 4.0, 40  # [s] how long after each demonstration's end home is taught, and how densely
BASIS_SPACING_S = 0.04  # [s] between the centres of the time basis; also its width
RELABEL_FRACTIONS = (0.25, 0.5, 0.75)  # extra expert queries between requests, as fractions of the period
RIDGE = 1e-6  # relative ridge penalty of the output fit


@dataclass(frozen=True)
class TrainingReport:
    """What ``train_demo_policy`` did, for the command's output and the model's metadata."""

    path: str
    cycles: int
    samples: int
    hidden: int
    rms_error_mrad: float  # over every joint and step of the training set
    max_error_mrad: float  # worst joint error on the training set
    seconds: float


class _Recorder:
    """Wraps the expert; keeps (inputs, first ``horizon`` steps) of every chunk it answers, and relabels."""

    def __init__(self, policy, horizon: int, period_ns: int):
        self.policy, self.horizon, self.period_ns = policy, horizon, period_ns
        self.source = policy.source
        self.map_document = getattr(policy, "map_document", None)  # the record states the expert's map
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
        self._keep(observation, chunk)
        for fraction in RELABEL_FRACTIONS:
            shifted = replace(observation, t_ns=observation.t_ns + round(fraction * self.period_ns))
            self._keep(shifted, self.policy.infer(shifted))
        return chunk

    def _keep(self, observation: Observation, chunk: ActionChunk) -> None:
        t = (observation.t_ns - self._t0) * 1e-9
        self.x.append(np.concatenate([[t], observation.measurements["part_in_camera"]]))
        self.y.append(np.asarray(chunk.actions[: self.horizon]).reshape(-1))


def collect_demonstrations(cycles: int, seed: int, horizon: int,
                           fixture_dx_mm: float = 0.0) -> tuple[np.ndarray, np.ndarray, float, tuple]:
    """Run the scripted program for ``cycles``: inputs (N, 4), targets (N, horizon*dof), dt [s], joint names.
    ``fixture_dx_mm``: demonstrations with the fixture moved in x (a clone taught on a mis-set cell)."""
    from cellguard.runtime import Run
    from cellguard.scenario import parse_scenario

    scenario = parse_scenario({"cell": "arm-pick-place", "seed": seed, "policy": "scripted",
                               "acceptance_cycles": cycles, "production_cycles": 0,
                               "faults": [{"kind": "fixture_shift", "at_cycle": 0, "dx_mm": fixture_dx_mm}]
                               if fixture_dx_mm else []})
    run = Run(scenario)
    recorder = _Recorder(run.policy, horizon, round(1e9 / scenario.policy_hz))
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


def fit_network(x: np.ndarray, y: np.ndarray, horizon: int, random_features: int, seed: int) -> Mlp:
    """The time basis and ``random_features`` random tanh units, output layer by ridge least squares."""
    rng = np.random.default_rng(seed)
    x_mean, x_std = x.mean(0), x.std(0) + 1e-9
    y_mean, y_std = y.mean(0), y.std(0) + 1e-9
    centres = np.arange(x[:, 0].min() - BASIS_SPACING_S, x[:, 0].max() + 2 * BASIS_SPACING_S, BASIS_SPACING_S)
    # unit k is tanh((t - c_k) / spacing), written on the normalised time input
    w_time = np.zeros((x.shape[1], len(centres)))
    w_time[0] = x_std[0] / BASIS_SPACING_S
    b_time = (x_mean[0] - centres) / BASIS_SPACING_S
    w_rand = rng.normal(0.0, 1.0, (x.shape[1], random_features))
    w1 = np.hstack([w_time, w_rand])
    b1 = np.concatenate([b_time, rng.normal(0.0, 1.0, random_features)])
    h = np.tanh(((x - x_mean) / x_std) @ w1 + b1)
    h1 = np.hstack([h, np.ones((len(h), 1))])
    gram = h1.T @ h1
    gram[np.diag_indices_from(gram)] += RIDGE * np.trace(gram) / len(gram)
    solution = np.linalg.solve(gram, h1.T @ ((y - y_mean) / y_std))
    return Mlp(inputs=INPUTS, weights=(w1, solution[:-1]), biases=(b1, solution[-1]), x_mean=x_mean, x_std=x_std,
               y_mean=y_mean, y_std=y_std, horizon=horizon)


def train_demo_policy(out: Path, cycles: int = 10, random_features: int = 64, horizon: int = 10,
                      seed: int = 0, fixture_dx_mm: float = 0.0, overwrite: bool = False) -> TrainingReport:
    """Record ``cycles`` scripted demonstrations, clone them, and save ``out`` (ONNX; a file there is replaced only
    with ``overwrite``, even one that appeared during the training)."""
    began = time.perf_counter()
    x, y, dt, joints = collect_demonstrations(cycles, seed, horizon, fixture_dx_mm)
    mlp = fit_network(x, y, horizon, random_features, seed)
    error = mlp.forward(x) - y
    path = save_mlp_onnx(mlp, Path(out), {
        "cellguard.action_names": ",".join(joints),
        "cellguard.dt_s": repr(dt),
        "cellguard.trained_on": f"{cycles} scripted arm-pick-place cycles, seed {seed}"
                                   + (f", fixture moved {fixture_dx_mm} mm in x" if fixture_dx_mm else ""),
    }, replace=overwrite)
    return TrainingReport(str(path), cycles, len(x), mlp.weights[0].shape[1], float(np.sqrt(np.mean(error**2))) * 1e3,
                          float(np.abs(error).max()) * 1e3, time.perf_counter() - began)
