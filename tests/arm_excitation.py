"""Shared by the identify tests: a short real arm excitation per module, and a copy of the arm's profile per test."""

from __future__ import annotations

from pathlib import Path

import pytest

from cellguard.calibrate.excitation import excitation_scenario, excite
from cellguard.robot.arm_cell import ASSETS

ARM = "arm-pick-place"


def arm_excitation(tmp_path_factory, seconds: float) -> Path:
    """A record of ``seconds`` of the arm's excitation (every tick, with motor current)."""
    out = tmp_path_factory.mktemp("identify") / "ex"
    excite(excitation_scenario(ARM, seconds), out)
    return out


@pytest.fixture(scope="module")
def excited(tmp_path_factory):
    """A 3 s arm excitation."""
    return arm_excitation(tmp_path_factory, 3.0)


@pytest.fixture
def profile(tmp_path) -> Path:
    """The arm's profile, copied: a test may write it."""
    path = tmp_path / "arm_profile.yaml"
    path.write_bytes((ASSETS / "arm_profile.yaml").read_bytes())
    return path
