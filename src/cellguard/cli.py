"""The ``cellguard`` command line. Bad input prints one line naming what is wrong, exit 2."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from cellguard.errors import CellguardError
from cellguard.scenario import Scenario, load_scenario

app = typer.Typer(add_completion=False, no_args_is_help=True, help="Adapt, guard, record and diagnose robot policies.")
embodiment_app = typer.Typer(no_args_is_help=True, help="Embodiment profiles of the registered cells.")
app.add_typer(embodiment_app, name="embodiment")
err = Console(stderr=True)

DEMO_SCENARIO = Path(__file__).parent / "scenarios" / "demo.yaml"


def _fail(exc: CellguardError) -> None:
    sys.stderr.write(f"error: {exc}\n")
    raise typer.Exit(2)


def _run(scenario: Scenario, out: Path, quiet: bool) -> dict:
    from cellguard.runner import run_scenario

    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=err, disable=quiet, transient=False) as progress:
        task = progress.add_task(f"{scenario.cell} cycles", total=scenario.total_cycles)

        def advance(outcome: dict) -> None:
            progress.update(task, advance=1, description=f"{scenario.cell} [{outcome['phase']}]")

        return run_scenario(scenario, out, on_cycle=advance)


def _print_summary(summary: dict, out: Path, as_json: bool) -> None:
    if as_json:
        sys.stdout.write(json.dumps({"out": str(out), "phases": summary["phases"],
                                     "events": len(summary["events"])}) + "\n")
        return
    console = Console()
    for phase, stats in summary["phases"].items():
        if stats["cycles"]:
            console.print(f"{phase}: {stats['cycles']} cycles, success {stats['success_rate']:.0%}")
    console.print(f"events: {len(summary['events'])}; written to {out}")


@app.command()
def run(
    scenario: Path = typer.Argument(..., help="Scenario YAML file."),
    out: Path = typer.Option(..., "--out", help="Folder for the record and summary.json."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON document on stdout."),
) -> None:
    """Run a scenario file on its simulated cell."""
    try:
        sc = load_scenario(scenario)
        summary = _run(sc, out, quiet=as_json)
    except CellguardError as exc:
        _fail(exc)
    _print_summary(summary, out, as_json)


@app.command()
def demo(
    out: Path = typer.Option(Path("cellguard-demo"), "--out", help="Folder for the demo's outputs."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON document on stdout."),
) -> None:
    """Acceptance then a production shift with site drift on the simulated arm cell."""
    try:
        sc = load_scenario(DEMO_SCENARIO)
        summary = _run(sc, out, quiet=as_json)
    except CellguardError as exc:
        _fail(exc)
    _print_summary(summary, out, as_json)


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
        _fail(exc)
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
