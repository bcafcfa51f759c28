"""`cellguard embodiment`: the profiles of the registered cells."""

from __future__ import annotations

import json
import sys

import typer
from rich.console import Console

from cellguard.cli.app import app
from cellguard.cli.errors import fail
from cellguard.errors import CellguardError

embodiment_app = typer.Typer(no_args_is_help=True, help="Embodiment profiles of the registered cells.")
app.add_typer(embodiment_app, name="embodiment")


@embodiment_app.command("show")
def embodiment_show(
    cell: str = typer.Argument(..., help="A registered cell, e.g. arm-pick-place."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON document on stdout."),
) -> None:
    """Print a cell's embodiment profile: joints, limits, measured parameters, symmetry."""
    from cellguard.robot.registry import make_cell

    try:
        profile = make_cell(cell).profile
    except CellguardError as exc:
        fail(exc)
    if as_json:
        sys.stdout.write(json.dumps(profile.to_dict(), indent=1) + "\n")
        return
    from rich.table import Table

    table = Table(title=f"{profile.robot} (profile {profile.version})")
    for col in ("joint", "kind", "position", "velocity", "acceleration", "jerk", "effort", "Kt"):
        table.add_column(col)
    for j in profile.joints:
        table.add_row(j.name, j.kind, f"[{j.position[0]:.3g}, {j.position[1]:.3g}]", f"{j.velocity:g}",
                      f"{j.acceleration:g}", f"{j.jerk:g}", f"{j.effort:g}", f"{j.torque_constant:g}")
    Console().print(table)
