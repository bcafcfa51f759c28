"""A quantity's number is written in ASCII digits, a dot and an exponent, as a file carries it: Python's float()
read "3_0 rad/s" as 30 rad/s, and took Arabic-Indic and full-width digits; each is now refused naming the number.
Any number written the plain way reads as float() reads it."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from cellguard.errors import ConfigError
from cellguard.units import parse_quantity

SPEED = ("angle/s",)


@pytest.mark.parametrize("number", ["3_0", "1_000.5", "\u0663", "\uff13", "0x10", "1e", "--1", "1.2.3"])
def test_a_number_not_written_in_plain_digits_is_refused_naming_it(number):
    with pytest.raises(ConfigError, match=f"f: '{number}' is not a number"):
        parse_quantity(f"{number} rad/s", "f", SPEED)


@given(st.floats(allow_nan=False, allow_infinity=False, min_value=-1e300, max_value=1e300))
def test_a_plain_number_reads_as_written(value):
    for text in (repr(value), f"{value:.6e}", f"{value:f}"):
        assert parse_quantity(f"{text} rad/s", "f", SPEED) == float(text)


@given(st.integers(-10**6, 10**6))
def test_degrees_convert_to_radians(n):
    assert parse_quantity(f"{n} deg/s", "f", SPEED) == pytest.approx(math.radians(n))
