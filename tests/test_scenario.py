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
        ({"faults": [{"kind": "servo_gain", "joint": [], "factor": 0.8}]}, "faults[0].joint: Value error, an empty "
                                                                           "list names no joint"),
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


def test_yaml_sets_and_binaries_are_refused_and_exponents_without_a_dot_are_numbers(tmp_path):
    """``site: !!set {a, b}`` ran with the text "{'a', 'b'}" recorded as the site; ``5e-1`` was the text "5e-1"."""
    for tag, value in (("!!set", "{a, b}"), ("!!binary", "aGVsbG8=")):
        (tmp_path / "s.yaml").write_text(f"cell: arm-pick-place\nsite: {tag} {value}\n")
        with pytest.raises(ScenarioError, match=f"site: a YAML {tag} is no scenario value"):
            load_scenario(tmp_path / "s.yaml")
    (tmp_path / "e.yaml").write_text("cell: arm-pick-place\nguard: {tool_speed_max: 5e-1, watchdog_s: 2E-1}\nseed: 7\n")
    scenario = load_scenario(tmp_path / "e.yaml")
    assert (scenario.guard.tool_speed_max, scenario.guard.watchdog_s, scenario.seed) == (0.5, 0.2, 7)


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


@pytest.mark.parametrize(("patch", "message"), [
    ({"acceptance_cycles": 0, "production_cycles": 0}, "acceptance_cycles, production_cycles: both 0"),
    ({"faults": [{"kind": "fixture_shift", "at_cycle": 2, "dx_mm": 4}]},
     "faults[0].at_cycle: fixture_shift at cycle 2 would never happen; the run's cycles (acceptance_cycles + "
     "production_cycles = 2) are numbered 0 to 1"),
    ({"faults": [{"kind": "tool_slip", "at_cycle": 0},
                 {"kind": "friction_growth", "joint": "elbow", "from_cycle": 99999, "per_cycle": 0.1}]},
     "faults[1].from_cycle: friction_growth at cycle 99999"),
    ({"process_changes": [{"kind": "payload", "at_cycle": 5, "grams": 40}]}, "process_changes[0].at_cycle: payload"),
])
def test_a_run_of_no_cycles_or_a_fault_after_its_last_cycle_is_refused(patch, message):
    """Both ran before: no cycles crashed at the retreat, a late fault never fired and said nothing."""
    with pytest.raises(ScenarioError) as info:
        parse_scenario({**BASE, **patch}, origin="s.yaml")
    assert str(info.value).startswith(f"s.yaml: {message}")
    assert "\n" not in str(info.value)


def test_a_release_plan_run_is_checked_with_its_own_cycle_counts():
    """A plan's run leaves production_cycles at 0: a fault at its acceptance_cycles is past its end."""
    from cellguard.release.plan import check_run

    check_run({"name": "ok", "acceptance_cycles": 3, "faults": [{"kind": "tool_slip", "at_cycle": 2}]}, "plan")
    with pytest.raises(ScenarioError, match=r"^plan: faults\[0\]\.at_cycle: .* = 3\) are numbered 0 to 2$"):
        check_run({"name": "late", "acceptance_cycles": 3, "faults": [{"kind": "tool_slip", "at_cycle": 3}]}, "plan")


@given(st.integers(0, 5), st.integers(0, 5), st.integers(0, 12))
def test_a_scenario_parses_exactly_when_it_has_cycles_and_its_fault_falls_in_them(acceptance, production, at):
    doc = {**BASE, "acceptance_cycles": acceptance, "production_cycles": production,
           "faults": [{"kind": "policy_nan", "at_cycle": at}]}
    try:
        sc = parse_scenario(doc)
    except ScenarioError as exc:
        assert not at < acceptance + production, str(exc)
    else:
        assert at < sc.total_cycles
