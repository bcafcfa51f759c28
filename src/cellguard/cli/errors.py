"""How every command ends on bad input: one line naming what is wrong, exit code 2."""

from __future__ import annotations

import sys

import typer

from cellguard.errors import CellguardError


def fail(exc: CellguardError) -> None:
    """Print ``error: <message>`` on stderr and exit 2, without a traceback."""
    sys.stderr.write(f"error: {exc}\n")
    raise typer.Exit(2)
