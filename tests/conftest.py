"""Shared fixtures: small scenarios and the arm cell's model."""

from __future__ import annotations

import sys

import pytest
from fleet_server import drop_session_stores, tag_session_stores

from cellguard.robot.arm_cell import ArmPickPlace


@pytest.fixture
def arm() -> ArmPickPlace:
    return ArmPickPlace(seed=1)


def pytest_runtest_logreport(report):
    """Tag the fleet stores this session made in the phase just run, so that a later session drops them should this
    one be killed."""
    tag_session_stores()


def pytest_sessionfinish(session):
    """Drop the fleet stores this session (this xdist worker) made on the tests' PostgreSQL server; what it cannot
    drop is named in one line on stderr (an xdist worker's is the run's own), never a failed run."""
    left = drop_session_stores()
    if left:
        print(left, file=sys.__stderr__)
