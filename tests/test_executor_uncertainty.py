"""A chunk's uncertainty is checked as its actions are: a value that is not a finite number >= 0 is refused naming the
step and the value (the refusal named the shape, which was right); numbers of another kind (text, complex, booleans)
are refused by their dtype (text raised out of the check, complex lost its imaginary part with a warning, booleans
read as 0 and 1)."""

from __future__ import annotations

import numpy as np
import pytest

from cellguard.control.executor import Executor
from cellguard.policy.chunk import ActionChunk
from cellguard.robot.registry import make_cell

CELL = make_cell("arm-pick-place")
Q0 = np.array(CELL.read().q, dtype=float)


def _problem(uncertainty) -> str | None:
    ex = Executor(CELL.profile, Q0, 1_000_000)
    return ex.prepare(ActionChunk(np.tile(Q0, (5, 1)), 0, 20_000_000, uncertainty=uncertainty)).problem


@pytest.mark.parametrize("value, said", [(np.nan, "nan at step 2"), (np.inf, "inf at step 2"), (-0.5, "-0.5 at step 2")])
def test_a_bad_uncertainty_value_is_named_with_its_step(value, said):
    unc = np.array([0.1, 0.2, value, 0.0, 0.0])
    assert _problem(unc) == f"uncertainty must be finite and >= 0, got {said}"


@pytest.mark.parametrize("unc", [np.array(["a"] * 5, dtype=object), np.array([1j] * 5), np.array([True] * 5),
                                 np.zeros(4)])
def test_an_uncertainty_of_another_kind_or_length_is_refused_by_its_dtype_and_shape(unc):
    assert _problem(unc) == f"uncertainty must be (5,) numbers, got shape {unc.shape}, dtype {unc.dtype}"


def test_a_good_uncertainty_passes():
    assert _problem(np.array([0.0, 0.1, 0.2, 0.3, 1e3])) is None
