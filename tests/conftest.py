"""Shared fixtures: small scenarios and the arm cell's model."""

from __future__ import annotations

import signal
import sys

import pytest
from fleet_server import drop_session_stores, tag_session_stores

from cellguard.robot.arm_cell import ArmPickPlace


def pytest_configure(config):
    """The stop signals at their defaults in the test process (an xdist worker too) and so in every process it starts:
    cellguard keeps a signal it finds ignored (``nohup``'s SIGHUP, a background job's SIGINT), so a suite started
    under nohup or with ``&`` from a script failed the tests that stop a run by a signal. The ignored case is tested on
    purpose (test_nohup.py)."""
    signal.signal(signal.SIGINT, signal.default_int_handler)
    for signum in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(signum, signal.SIG_DFL)


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
