"""Shared fixtures: small scenarios and the arm cell's model."""

from __future__ import annotations

import signal
import sys

import pytest
from fleet_server import drop_session_stores, tag_session_stores

from cellguard.robot.arm_cell import ArmPickPlace


def pytest_configure(config):
    """No stop signal ignored in the test process (an xdist worker too), so none in the programs it starts: cellguard
    keeps a signal it finds ignored (``nohup``'s SIGHUP, a background job's SIGINT), and a suite started under nohup
    or with ``&`` from a script failed the tests that stop a run by a signal. An ignored one becomes a handler that
    does nothing: the suite itself still outlives the hangup nohup was for (a program started by exec gets the
    default, as a handler is not inherited), and cellguard's own handlers take over where a test installs them. The
    ignored case is tested on purpose (test_nohup.py)."""
    for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        if signal.getsignal(signum) is signal.SIG_IGN:
            signal.signal(signum, _ignored)


def _ignored(signum, frame) -> None:
    """A signal the suite was started ignoring, still without effect on it."""


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
