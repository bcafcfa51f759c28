"""The root ``typer`` application; each command group registers itself from its own module."""

from __future__ import annotations

import typer

app = typer.Typer(add_completion=False, no_args_is_help=True, help="Adapt, guard, record and diagnose robot policies.")
