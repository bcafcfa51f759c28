"""Probable causes on real simulated runs of the arm cell: every fault kind named from its pattern.

Faults that leave different traces share a run (a fixture shift with friction and a weak servo;
a knocked camera with a slow policy; a slipped tool with a NaN chunk), which also checks that
concurrent causes are told apart. Runs are short: the arm cell costs most of this suite's time.
"""

from __future__ import annotations

from functools import lru_cache

import pytest

from cellguard.diagnose import diagnose
from cellguard.runtime import Run
from cellguard.scenario import parse_scenario

ACCEPTANCE, AT = 6, 7  # the faults start at the second production cycle

RUNS = {
    "mechanical": ([{"kind": "fixture_shift", "at_cycle": AT, "dx_mm": 3.0},
                    {"kind": "friction_growth", "joint": "elbow", "from_cycle": AT, "per_cycle": 0.15},
                    {"kind": "servo_gain", "joint": "shoulder_lift", "factor": 0.7, "at_cycle": AT}],
                   {("fixture_shift", ()), ("friction", ("elbow",)), ("servo", ("shoulder_lift",))}),
    "camera_and_latency": ([{"kind": "camera_shift", "at_cycle": AT, "dx_mm": 0.0, "dy_mm": 3.0},
                            {"kind": "policy_latency", "at_cycle": AT, "ms": 100}],
                           {("camera_shift", ()), ("policy_latency", ())}),
    "tool_and_nan": ([{"kind": "tool_slip", "at_cycle": AT, "dx_mm": 2.0},
                      {"kind": "policy_nan", "at_cycle": AT + 1}],
                     {("tool_slip", ()), ("policy_output", ())}),
}


@lru_cache(maxsize=None)
def _run(name: str, production: int = 4, seed: int = 4) -> Run:
    faults = RUNS[name][0] if name in RUNS else []
    run = Run(parse_scenario({"cell": "arm-pick-place", "seed": seed, "acceptance_cycles": ACCEPTANCE,
                              "production_cycles": production, "faults": faults}))
    for _ in range(ACCEPTANCE + production):
        run.cycle()
    return run


@pytest.mark.parametrize("name", sorted(RUNS))
def test_each_fault_kind_is_detected_and_named(name):
    run = _run(name)
    d = diagnose(run.cycles, run.events, {})
    named = {(f.cause, f.joints) for f in d.findings}
    assert named == RUNS[name][1], [f.to_dict() for f in d.findings]
    for f in d.findings:
        assert AT - 1 <= f.cycle <= AT + 2 and 0.5 <= f.confidence <= 1.0 and f.evidence
    assert not [a for a in d.drift.alarms if a.cycle < AT]
    assert d.first_faulted_cycle == min(f.cycle for f in d.findings) == d.last_good_cycle + 1


def test_fixture_shift_evidence_names_the_move():
    f = next(f for f in diagnose(_run("mechanical").cycles, [], {}).findings if f.cause == "fixture_shift")
    text = " ".join(f.evidence)
    assert "camera-seen part and fixture moved +3.0 mm in x" in text and "grasp pose moved +3." in text
    assert "fixture moved" in text


def test_a_fault_free_run_has_no_finding():
    run = _run("none", production=6, seed=9)
    d = diagnose(run.cycles, run.events, {})
    assert d.findings == () and d.drift.alarms == () and d.first_faulted_cycle is None
