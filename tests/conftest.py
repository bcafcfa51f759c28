"""Shared fixtures: small scenarios and the arm cell's model."""

from __future__ import annotations

import pytest

from cellguard.robot.arm_cell import ArmPickPlace


@pytest.fixture
def arm() -> ArmPickPlace:
    return ArmPickPlace(seed=1)
