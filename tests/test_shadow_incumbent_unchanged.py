"""Shadow mode leaves the incumbent's run as it is: building the candidate's guard measured the cell again, one
draw of its sensor noise, and the same scenario and seed placed the part 0.22 mm off instead of 0.08 mm."""

from __future__ import annotations

import numpy as np
import pytest
from release_helpers import CELL, replay_file

from cellguard.control.config import GuardConfig
from cellguard.record.reader import open_record
from cellguard.release.shadow import ShadowRun
from cellguard.runtime import run_scenario
from cellguard.scenario import parse_scenario


def _ticks(folder):
    with open_record(folder) as rec:
        return rec.ticks()


def test_the_incumbents_record_is_the_same_with_and_without_a_shadow(tmp_path):
    def scenario():
        return parse_scenario({"cell": CELL, "seed": 9, "policy": "scripted", "acceptance_cycles": 1,
                               "production_cycles": 0})

    wild = replay_file(tmp_path / "wild.npz", offset=0.4)  # a candidate far from the incumbent: it must not matter
    plain = run_scenario(scenario(), tmp_path / "plain")
    sc = scenario()
    shadowed = run_scenario(sc, tmp_path / "shadow", run=ShadowRun(sc, f"replay:{wild}", GuardConfig()))
    a, b = _ticks(tmp_path / "plain"), _ticks(tmp_path / "shadow")
    assert len(a) > 100 and len(a) == len(b)
    for field in ("t_ns", "q_ref", "q_cmd", "q_meas", "qd_meas", "effort"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)
    assert shadowed["cycles"][0]["place_error_mm"] == plain["cycles"][0]["place_error_mm"]


def test_an_onnx_candidate_leaves_the_incumbents_record_as_it_is(tmp_path):
    """An ONNX adapter observes the cell while it is built (to learn the model's inputs): two draws of camera noise,
    and every measurement of the incumbent's run after them differed from the run without a shadow (444 of 445
    ticks)."""
    pytest.importorskip("onnxruntime")
    from foreign_arm import taught_program

    from cellguard.policy.onnx_export import save_mlp_onnx, trajectory_mlp

    from cellguard.robot.registry import make_cell

    times, points = taught_program()
    joints = ",".join(make_cell(CELL).profile.joint_names)
    model = save_mlp_onnx(trajectory_mlp(times, points, horizon=10, dt_s=0.02), tmp_path / "pick.onnx",
                          {"cellguard.action_names": joints, "cellguard.dt_s": "0.02"})

    def scenario():
        return parse_scenario({"cell": CELL, "seed": 9, "policy": "scripted", "acceptance_cycles": 1,
                               "production_cycles": 0})

    run_scenario(scenario(), tmp_path / "plain")
    sc = scenario()
    run_scenario(sc, tmp_path / "shadow", run=ShadowRun(sc, f"onnx:{model}", GuardConfig()))
    a, b = _ticks(tmp_path / "plain"), _ticks(tmp_path / "shadow")
    assert len(a) > 100 and len(a) == len(b)
    for field in ("q_ref", "q_cmd", "q_meas", "effort"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)
