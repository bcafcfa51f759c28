"""How every command ends on bad input: one line naming what is wrong, exit code 2."""

from __future__ import annotations

import sys

import typer

from cellguard.cli.text import printable
from cellguard.errors import CellguardError


def fail(exc: CellguardError) -> None:
    """Print ``error: <message>`` on stderr, on one line with no control characters, and exit 2."""
    sys.stderr.write(f"error: {printable(exc)}\n")
    raise typer.Exit(2)
