"""Whole numbers in every YAML input read as YAML 1.2 reads them: ``020`` is 20, not YAML 1.1's octal 16, and
``1:05`` is text, not base 60 (a scenario's ``production_cycles: 010`` ran 8 cycles, ``at_cycle: 012`` fired at 10)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from cellguard.errors import ConfigError
from cellguard.scenario import load_scenario
from cellguard.yaml_file import parse_yaml


def value(text: str):
    return parse_yaml(f"v: {text}\n", "test")["v"]


@given(st.integers(0, 10**12), st.integers(0, 4), st.sampled_from(["", "-", "+"]))
def test_a_zero_padded_number_is_the_decimal_written(n, zeros, sign):
    assert value(f"{sign}{'0' * zeros}{n}") == (-n if sign == "-" else n)


@given(st.integers(0, 10**12))
def test_octal_and_hex_say_so_with_their_prefix(n):
    assert value(f"0o{n:o}") == n and value(f"0x{n:X}") == n == value(f"!!int 0o{n:o}")


@given(st.integers(0, 99), st.integers(0, 59), st.sampled_from(["", ".5"]))
def test_hours_and_minutes_are_text_not_base_60(hours, minutes, fraction):
    text = f"{hours}:{minutes:02d}{fraction}"
    assert value(text) == text


@pytest.mark.parametrize("text", ["!!int 010", "!!int 0010"])
def test_an_explicit_int_tag_is_decimal_too(text):
    assert value(text) == int(text.split()[1], 10)


@pytest.mark.parametrize("text", ["!!int 1:05", "!!float 1:30", "!!int 0b11"])
def test_an_explicit_tag_on_a_yaml_1_1_only_form_is_refused(text):
    with pytest.raises(ConfigError, match=r"^test: not valid YAML \("):
        value(text)


def test_a_scenario_with_zero_padded_numbers_runs_what_it_says(tmp_path):
    path = tmp_path / "octal.yaml"
    path.write_text("cell: arm-pick-place\nseed: 007\npolicy_hz: 020\nacceptance_cycles: 5\nproduction_cycles: 010\n"
                    "faults:\n  - {kind: fixture_shift, at_cycle: 012, dx_mm: 010}\n")
    scenario = load_scenario(path)
    assert (scenario.seed, scenario.policy_hz, scenario.production_cycles) == (7, 20.0, 10)
    assert (scenario.faults[0].at_cycle, scenario.faults[0].dx_mm) == (12, 10.0)
