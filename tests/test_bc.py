"""The learned arm policy: a few scripted demonstrations, cloned, run through the whole tick path."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("onnxruntime")
pytest.importorskip("onnx")

from cellguard.train.demo_policy import collect_demonstrations, train_demo_policy  # noqa: E402
from cellguard.runtime import Run  # noqa: E402
from cellguard.scenario import parse_scenario  # noqa: E402


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    path = tmp_path_factory.mktemp("bc") / "demo.onnx"
    return path, train_demo_policy(path, cycles=3, random_features=32, seed=1)


def test_tracks_the_taught_program_on_demonstrations_it_did_not_see(model):
    import onnxruntime as ort

    path, report = model
    assert report.max_error_mrad < 5.0
    x, y, _, _ = collect_demonstrations(1, seed=9, horizon=10)  # another seed: other camera noise, other cycle
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    out = np.vstack([session.run(None, {"time_s": row[:1].reshape(1, 1).astype(np.float32),
                                         "part_in_camera": row[1:].reshape(1, 3).astype(np.float32)})[0].reshape(1, -1)
                     for row in x])
    error = np.abs(out - y).reshape(len(x), 10, -1)
    assert error.max() < 0.005  # [rad] every joint, every step of every chunk, within 5 mrad
    assert np.sqrt(np.mean(error**2)) < 0.001


def test_learned_policy_completes_cycles_inside_the_envelope(model):
    path, _ = model
    run = Run(parse_scenario({"cell": "arm-pick-place", "seed": 5, "policy": f"onnx:{path}",
                              "acceptance_cycles": 3, "production_cycles": 0}))
    outcomes = [run.cycle() for _ in range(3)]
    assert all(o["success"] and not o["timed_out"] for o in outcomes)
    assert max(o["place_error_mm"] for o in outcomes) < 2.0
    assert [e.kind for e in run.events] == []  # the clone never asked the envelope to intervene
