"""The root ``typer`` application; each command group registers itself from its own module."""

from __future__ import annotations

import typer

from cellguard.cli import stdout
from cellguard.ending import ended_by_signals

app = typer.Typer(add_completion=False, no_args_is_help=True, help="Adapt, guard, record and diagnose robot policies.")


@app.callback()
def _root(ctx: typer.Context) -> None:
    """Adapt, guard, record and diagnose robot policies."""
    stdout.guard()  # a stdout that cannot be written ends any command in one line
    ctx.with_resource(ended_by_signals())
