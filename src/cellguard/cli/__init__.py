"""The ``cellguard`` command line, one module per command group. Bad input: one line, exit 2.

A new command group is a new module here that imports ``app`` from ``cellguard.cli.app`` and
registers its commands; add its import below.
"""

from cellguard.cli import (  # noqa: F401  (register commands)
    bench, calibrate, diagnose, embodiment, fleet, policy, record, release, run, sim_server)
from cellguard.cli.app import app

__all__ = ["app"]
