"""`cellguard bench`: performance figures, one group per benchmark; never asserted."""

from __future__ import annotations

import json
import sys

import typer
from rich.console import Console

from cellguard.cli.app import app
from cellguard.cli.errors import fail
from cellguard.errors import CellguardError


def _record_figures(quick: bool) -> dict:
    from cellguard.bench.record import figures

    return figures(quick=quick)


def _guard_figures(quick: bool) -> dict:
    from cellguard.bench.guard import figures

    return figures(quick=quick)


BENCHMARKS: dict = {"record": _record_figures, "guard": _guard_figures}  # name -> function(quick) -> {figure: value}


@app.command()
def bench(
    only: list[str] = typer.Option(None, "--only", help=f"Run only these groups: {', '.join(BENCHMARKS)}."),
    quick: bool = typer.Option(False, "--quick", help="Shorter runs (rougher figures)."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON document on stdout."),
) -> None:
    """Performance figures (timings, sizes), one group per benchmark."""
    from cellguard.errors import UnknownNameError

    try:
        for name in only or ():
            if name not in BENCHMARKS:
                raise UnknownNameError("benchmark", name, list(BENCHMARKS))
    except CellguardError as exc:
        fail(exc)
    results = {name: fn(quick) for name, fn in BENCHMARKS.items() if not only or name in only}
    if as_json:
        sys.stdout.write(json.dumps(results, indent=1) + "\n")
        return
    console = Console()
    for name, figures in results.items():
        console.print(f"[bold]{name}[/bold]")
        for key, value in figures.items():
            console.print(f"  {key:<32} {value:.4g}" if isinstance(value, float) else f"  {key:<32} {value}")
