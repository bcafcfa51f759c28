"""Whole numbers in every YAML input read as YAML 1.2 reads them: ``020`` is 20, not YAML 1.1's octal 16, and
``1:05`` is text, not base 60 (a scenario's ``production_cycles: 010`` ran 8 cycles, ``at_cycle: 012`` fired at 10)."""

from __future__ import annotations

import re

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


@given(st.floats(0, 1, exclude_max=True), st.sampled_from(["-", "+"]))
def test_a_signed_fraction_without_a_leading_zero_is_a_number(x, sign):
    """``-.5`` was the text "-.5" (YAML 1.1), which a number field refused; ``!!float`` of it was -0.5 all along."""
    text = sign + repr(x).removeprefix("0")
    assert value(text) == value(f"!!float {text}") == (-x if sign == "-" else x)


@pytest.mark.parametrize("text", ["!!int 010", "!!int 0010"])
def test_an_explicit_int_tag_is_decimal_too(text):
    assert value(text) == int(text.split()[1], 10)


@pytest.mark.parametrize("text", ["!!int 1:05", "!!float 1:30", "!!int 0b11", "!!int 1e3", "!!int 0o", "!!int 0x_",
                                  "!!int 1_", "!!float 0x10", "!!float 1_e3", "!!float 1._"])
def test_an_explicit_tag_on_a_yaml_1_1_only_form_is_refused_naming_it(text):
    """Python's own ``invalid literal for int() with base 10: '0b11'`` was the message, or 1000.0 for ``1_e3``."""
    tag, written = text.split()
    with pytest.raises(ConfigError) as refused:
        value(text)
    assert str(refused.value).startswith(f"test: line 1: {tag} {written!r} is not ")
    assert "\n" not in str(refused.value) and "int()" not in str(refused.value)


_BASES = {"": ("0123456789", 10), "0o": ("01234567", 8), "0x": ("0123456789abcdefABCDEF", 16)}


@st.composite
def _groups(draw) -> tuple[str, list[str], int]:
    """A prefix, groups of its digits (to join with ``_``) and its base."""
    prefix = draw(st.sampled_from(sorted(_BASES)))
    alphabet, base = _BASES[prefix]
    return prefix, draw(st.lists(st.text(alphabet, min_size=1, max_size=4), min_size=1, max_size=4)), base


@given(_groups())
def test_an_underscore_between_two_digits_separates_them(written):
    prefix, groups, base = written
    text = prefix + "_".join(groups)
    assert value(text) == int("".join(groups), base) == value(f"!!int {text}")


@given(_groups(), st.sampled_from(["{p}{d}_", "{p}_{d}", "{p}{d}__{d}"]))
def test_an_underscore_not_between_two_digits_is_text(written, form):
    """``1_``, ``1__0`` and ``0x_1`` were read as 1, 10 and 1; ``0o_`` failed in ``int()``."""
    prefix, groups, _ = written
    text = form.format(p=prefix, d="_".join(groups))
    assert value(text) == text
    with pytest.raises(ConfigError, match=f"^test: line 1: !!int {re.escape(repr(text))} is not a whole number"):
        value(f"!!int {text}")


@given(st.text(st.characters(categories=["Nd"], exclude_characters="0123456789"), min_size=1, max_size=3))
def test_digits_other_than_ascii_are_text_and_refused_as_an_int(digits):
    """``int()`` takes any Unicode digit: ``!!int ٣`` read as 3."""
    assert value(digits) == digits
    for tag in ("!!int", "!!float"):
        with pytest.raises(ConfigError, match=f"^test: line 1: {tag} {re.escape(repr(digits))} is not "):
            value(f"{tag} {digits}")


def test_a_scenario_with_zero_padded_numbers_runs_what_it_says(tmp_path):
    path = tmp_path / "octal.yaml"
    path.write_text("cell: arm-pick-place\nseed: 007\npolicy_hz: 020\nacceptance_cycles: 5\nproduction_cycles: 010\n"
                    "faults:\n  - {kind: fixture_shift, at_cycle: 012, dx_mm: 010}\n")
    scenario = load_scenario(path)
    assert (scenario.seed, scenario.policy_hz, scenario.production_cycles) == (7, 20.0, 10)
    assert (scenario.faults[0].at_cycle, scenario.faults[0].dx_mm) == (12, 10.0)
