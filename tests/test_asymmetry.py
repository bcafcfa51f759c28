"""Mirrored asymmetry on the quadruped: a weak left side is named; a healthy robot shows none."""

from __future__ import annotations

import pytest

from cellguard.diagnose import as_cycles, diagnose, mirrored_asymmetry
from cellguard.diagnose.asymmetry import mirror_map
from cellguard.embodiment.profile import SymmetryPair
from cellguard.runtime import Run
from cellguard.scenario import parse_scenario

LEFT = ["fl_abduction", "fl_hip", "fl_knee", "rl_abduction", "rl_hip", "rl_knee"]


def _cycles(faults: list[dict], n: int = 8):
    run = Run(parse_scenario({"cell": "quadruped-turns", "seed": 2, "acceptance_cycles": 0, "production_cycles": n,
                              "faults": faults}))
    for _ in range(n):
        run.cycle()
    return run


@pytest.fixture(scope="module")
def healthy():
    return _run_cached([])


@pytest.fixture(scope="module")
def weak_left():
    return _run_cached([{"kind": "servo_gain", "joint": LEFT, "factor": 0.8}])


def _run_cached(faults):
    run = _cycles(faults, n=14)
    return run, as_cycles(run.cycles)


def test_mirror_map_pairs_joints_and_the_legs_they_imply():
    pairs = (SymmetryPair("fl_hip", "fr_hip", 1.0), SymmetryPair("rl_knee", "rr_knee", 1.0))
    assert mirror_map(pairs) == {"fl_hip": "fr_hip", "rl_knee": "rr_knee", "fl": "fr", "rl": "rr"}


def test_no_asymmetry_without_a_fault(healthy):
    run, cycles = healthy
    a = mirrored_asymmetry(cycles, run.cell.profile.symmetry)
    assert a is not None and a.side is None and a.significant == ()
    assert len({c.label for c in cycles}) == 2  # left and right turns were both compared


def test_weak_left_servos_name_the_left_side_and_its_joints(weak_left):
    run, cycles = weak_left
    a = mirrored_asymmetry(cycles, run.cell.profile.symmetry)
    assert a.side == "left"
    assert set(a.joints) <= set(LEFT) and len(a.joints) >= 3
    tracking = [d for d in a.significant if d.feature.startswith("tracking_rms.")]
    assert tracking and all(d.relative > 0.05 for d in tracking)  # the left joints track worse, by > 5 %
    assert any("%" in e for e in a.evidence)


def test_diagnosis_reports_the_side_as_a_servo_finding(weak_left):
    run, _ = weak_left
    rows = [{**c, "phase": "acceptance" if c["cycle"] < 10 else "production"} for c in run.cycles]
    d = diagnose(rows, run.events, {}, symmetry=run.cell.profile.symmetry)
    assert d.asymmetry.side == "left"
    assert any(f.cause == "servo" and set(f.joints) <= set(LEFT) for f in d.findings)
    assert d.to_dict()["asymmetry"]["side"] == "left"


def test_a_cell_without_symmetry_map_has_no_asymmetry_section():
    assert mirrored_asymmetry([], ()) is None
