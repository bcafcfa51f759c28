"""Shared fixtures: small scenarios and the arm cell's model."""

from __future__ import annotations

import pytest
from fleet_server import drop_session_stores

from cellguard.robot.arm_cell import ArmPickPlace


@pytest.fixture
def arm() -> ArmPickPlace:
    return ArmPickPlace(seed=1)


def pytest_sessionfinish(session):
    """Drop the fleet stores this session (this xdist worker) made on the tests' PostgreSQL server."""
    drop_session_stores()
