"""A policy's step period is stated, never guessed: ``?dt=``, else the model's or the server's metadata.

A source that states neither is refused before anything moves, naming what to give: a default of 20 ms played a
Diffusion-Policy-shaped model (16 steps of 100 ms) five times too fast (8 workspace stops in 2 cycles, a 304 mm
place error, exit 0), and openpi's own servers never send ``dt_s``.
"""

from __future__ import annotations

import re

import pytest
import yaml
from cli_util import one_error
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import ConfigError
from cellguard.policy.registry import make_policy
from cellguard.robot.arm_cell import ArmPickPlace

JOINTS = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_flex", "wrist_roll", "gripper"]


def _refusal(source: str) -> str:
    return (rf"^policy: {re.escape(source)}: the step period is not stated: give \?dt=SECONDS \(the policy's "
            rf"control period, e\.g\. 0\.0667 for 15 Hz\)$")


def _onnx(path, **metadata):
    """A one-step ONNX model naming the arm's joints (the hostile tests' own), with ``metadata`` besides."""
    pytest.importorskip("onnxruntime")
    pytest.importorskip("onnx")
    from hostile.test_tracebacks import small_onnx

    return small_onnx(path, **metadata)


def test_an_onnx_model_without_a_stated_period_is_refused_naming_what_to_give(tmp_path):
    model = _onnx(tmp_path / "dp.onnx")
    with pytest.raises(ConfigError, match=_refusal(f"onnx:{model}")):
        make_policy(f"onnx:{model}", ArmPickPlace())


@pytest.mark.parametrize("metadata, query, dt_ms", [({}, "?dt=0.1", 100), ({"cellguard.dt_s": "0.05"}, "", 50),
                                                    ({"cellguard.dt_s": "0.05"}, "?dt=0.1", 100)])
def test_an_onnx_period_comes_from_dt_else_from_the_model(tmp_path, metadata, query, dt_ms):
    model = _onnx(tmp_path / "m.onnx", **metadata)
    assert make_policy(f"onnx:{model}{query}", ArmPickPlace()).dt_ns == dt_ms * 1_000_000


def test_a_run_of_a_policy_without_a_period_is_one_line_exit_2_and_nothing_moves(tmp_path):
    model = _onnx(tmp_path / "dp.onnx")
    scenario = tmp_path / "s.yaml"
    scenario.write_text(yaml.safe_dump({"cell": "arm-pick-place", "seed": 5, "policy": f"onnx:{model}",
                                        "acceptance_cycles": 2, "production_cycles": 0}))
    out = tmp_path / "out"
    line = one_error(CliRunner().invoke(app, ["run", str(scenario), "--out", str(out)]))
    assert "the step period is not stated: give ?dt=SECONDS" in line and f"onnx:{model}" in line
    assert not out.exists()


def _openpi_server(metadata: dict):
    """A websocket server on 127.0.0.1 sending openpi metadata naming the arm's joints, and ``metadata``."""
    pytest.importorskip("websockets")
    pytest.importorskip("msgpack")
    from hostile.wsserver import serve_bytes

    from cellguard.policy.wire import packb

    return serve_bytes(packb({"action_names": JOINTS, **metadata}))


def test_an_openpi_server_without_dt_s_is_refused_naming_what_to_give():
    """openpi's own servers send no ``dt_s``: their address alone, as in openpi's examples, is refused."""
    with _openpi_server({}) as uri, pytest.raises(ConfigError, match=_refusal(f"openpi:{uri}")):
        make_policy(f"openpi:{uri}", ArmPickPlace())


@pytest.mark.parametrize("metadata, query, dt_ns", [({}, "?dt=0.0667", 66_700_000), ({"dt_s": 0.05}, "", 50_000_000),
                                                    ({"dt_s": 0.05}, "?dt=0.0667", 66_700_000)])
def test_an_openpi_period_comes_from_dt_else_from_the_server(metadata, query, dt_ns):
    with _openpi_server(metadata) as uri:
        policy = make_policy(f"openpi:{uri}{query}", ArmPickPlace())
        try:
            assert policy.dt_ns == dt_ns
        finally:
            policy.close()


def test_a_release_frozen_without_a_period_says_it_is_the_release_and_what_to_do(tmp_path):
    """A release made before the period was required: its refusal said `--policy:`, an option `release run` has not,
    and `give ?dt=`, which cannot be done to a frozen release."""
    from cellguard.release.bundle import Bundle, policy_hash
    from cellguard.release.errors import ReleaseError

    model = _onnx(tmp_path / "dp.onnx")
    old = Bundle("r-0001", {"profile": {"cell": "arm-pick-place"}, "policy": {"spec": f"onnx:{model}"},
                            "action_map": None})
    with pytest.raises(ReleaseError, match=r"^release r-0001: its policy \(create a new release to change it\): "
                                           r"policy: onnx:.* the step period is not stated"):
        policy_hash(old)
