"""Scenario validation: each bad input gives one error naming the key; nothing runs."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from cellguard.errors import ScenarioError, UnknownNameError
from cellguard.runtime import Run
from cellguard.scenario import load_scenario, parse_scenario

BASE = {"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 1}


@pytest.mark.parametrize(
    ("patch", "message"),
    [
        ({"colour": "red"}, "colour: unknown key"),
        ({"seed": "seven"}, "seed: Input should be a valid integer"),
        ({"acceptance_cycles": -1}, "acceptance_cycles: Input should be greater than or equal to 0"),
        ({"policy_hz": 500}, "policy_hz: Input should be less than or equal to 50"),
        ({"faults": [{"kind": "meteor", "at_cycle": 1}]}, "faults[0]: unknown fault kind"),
        ({"faults": [{"kind": "fixture_shift", "at_cycle": 1, "dx_mm": 900}]}, "faults[0].dx_mm: Input should be less"),
        ({"faults": [{"kind": "fixture_shift", "dx_mm": 1}]}, "faults[0].at_cycle: Field required"),
        ({"faults": [{"kind": "tool_slip", "at_cycle": 1, "dq_mm": 1}]}, "faults[0].dq_mm: unknown key"),
        ({"faults": [{"kind": "servo_gain", "joint": "elbow", "factor": 0}]}, "faults[0].factor"),
        ({"seed": -1}, "seed: Input should be greater than or equal to 0"),
        ({"faults": [{"kind": "policy_latency", "at_cycle": 5, "ms": 50, "until_cycle": 2}]},
         "until_cycle 2 is before at_cycle 5"),
        ({"guard": {"box": [[0.5, -0.5, 0.0], [0.4, 0.5, 0.5]]}}, "guard.box: Value error, each minimum must be below"),
    ],
)
def test_bad_scenario_names_the_key(patch, message):
    with pytest.raises(ScenarioError) as info:
        parse_scenario({**BASE, **patch})
    assert message in str(info.value)
    assert "\n" not in str(info.value)


def test_unknown_joint_and_cell_are_refused_before_running():
    sc = parse_scenario({**BASE, "faults": [{"kind": "friction_growth", "joint": "knee", "from_cycle": 0, "per_cycle": 0.1}]})
    with pytest.raises(ScenarioError, match=r"faults\[0\].joint: 'knee' is not a joint"):
        Run(sc)
    with pytest.raises(UnknownNameError, match="unknown cell 'lathe'; known: arm-pick-place"):
        Run(parse_scenario({**BASE, "cell": "lathe"}))


def test_unknown_policy_scheme_lists_known():
    with pytest.raises(UnknownNameError, match="unknown policy source 'carrier-pigeon'"):
        Run(parse_scenario({**BASE, "policy": "carrier-pigeon:x"}))


def test_files(tmp_path):
    with pytest.raises(ScenarioError, match="no such scenario file"):
        load_scenario(tmp_path / "missing.yaml")
    (tmp_path / "list.yaml").write_text("- a\n- b\n")
    with pytest.raises(ScenarioError, match="expected a mapping"):
        load_scenario(tmp_path / "list.yaml")
    (tmp_path / "broken.yaml").write_text("cell: [")
    with pytest.raises(ScenarioError, match="not valid YAML"):
        load_scenario(tmp_path / "broken.yaml")


@given(st.dictionaries(st.text(max_size=8), st.one_of(st.integers(), st.text(max_size=5), st.none()), max_size=4))
def test_arbitrary_documents_never_escape_as_other_errors(doc):
    try:
        parse_scenario({**BASE, **doc})
    except ScenarioError as exc:
        assert str(exc)
