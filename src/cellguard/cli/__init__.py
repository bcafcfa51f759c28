"""The ``cellguard`` command line, one module per command group. Bad input: one line, exit 2.

A new command group is a new module here that imports ``app`` from ``cellguard.cli.app`` and
registers its commands; add its import below.
"""

from cellguard.cli import bench, calibrate, diagnose, embodiment, fleet, policy, record, run, sim_server  # noqa: F401  (register commands)
from cellguard.cli.app import app

__all__ = ["app"]
