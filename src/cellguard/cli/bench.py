"""`cellguard bench`: performance figures, one group per benchmark; never asserted."""

from __future__ import annotations

import json
import sys

import typer
from rich.console import Console
from rich.text import Text

from cellguard.cli.app import app
from cellguard.cli.errors import fail
from cellguard.cli.text import say
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
    results = {}
    for name, fn in BENCHMARKS.items():  # a full or unwritable TMPDIR is one line, not a traceback; no figures
        if not only or name in only:
            try:
                results[name] = fn(quick)
            except CellguardError as exc:
                fail(CellguardError(f"benchmark {name}: {exc}"))
            except OSError as exc:  # a temporary file written outside the recorder (index parts, ...)
                where = f"{exc.filename}: " if exc.filename else ""
                fail(CellguardError(f"benchmark {name}: {where}{exc.strerror or exc}"))
            except KeyboardInterrupt:  # Ctrl-C: the recording's writer finishes at exit (RunRecording), then this
                sys.stderr.write(f"error: benchmark {name}: stopped by the operator (SIGINT); no figures\n")
                raise typer.Exit(130) from None
    if as_json:
        sys.stdout.write(json.dumps(results, indent=1) + "\n")
        return
    console = Console()
    for name, figures in results.items():
        console.print(Text(name, style="bold"))
        for key, value in figures.items():  # a value may hold a path (record_failed): as it is, no markup
            say(f"  {key:<32} {value:.4g}" if isinstance(value, float) else f"  {key:<32} {value}", err=False)
