"""The ``cellguard`` command line. Bad input prints one line naming what is wrong, exit 2."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import typer
from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
)

from cellguard.cli_errors import fail
from cellguard.errors import CellguardError
from cellguard.output import make_folder
from cellguard.record.cli import record_app
from cellguard.scenario import Scenario, load_scenario

app = typer.Typer(add_completion=False, no_args_is_help=True, help="Adapt, guard, record and diagnose robot policies.")
embodiment_app = typer.Typer(no_args_is_help=True, help="Embodiment profiles of the registered cells.")
app.add_typer(embodiment_app, name="embodiment")
app.add_typer(record_app, name="record")
err = Console(stderr=True)

DEMO_SCENARIO = Path(__file__).parent / "scenarios" / "demo.yaml"


def _run(scenario: Scenario, out: Path, quiet: bool) -> dict:
    from cellguard.runner import run_scenario

    make_folder(out, "--out")  # before the progress bar: a bad folder is one line and nothing else
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
        fail(exc)
    _print_summary(summary, out, as_json)


@app.command()
def demo(
    out: Path = typer.Option(Path("cellguard-demo"), "--out", help="Folder for the demo's outputs."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON document on stdout."),
) -> None:
    """Acceptance then a production shift with site drift on the simulated arm cell."""
    from cellguard.diagnose.from_record import diagnose_record
    from cellguard.report.from_record import write_report

    try:
        sc = load_scenario(DEMO_SCENARIO)
        summary = _run(sc, out, quiet=as_json)
        diagnosis = diagnose_record(out)
        report_path = write_report(out, diagnosis=diagnosis)
    except CellguardError as exc:
        fail(exc)
    if as_json:
        sys.stdout.write(json.dumps({"out": str(out), "phases": summary["phases"], "events": len(summary["events"]),
                                     "diagnosis": diagnosis.to_dict(), "report": str(report_path)}) + "\n")
        return
    _print_summary(summary, out, as_json)
    _print_diagnosis(diagnosis)
    Console().print(f"report: {report_path}")


@app.command()
def diagnose(
    folder: Path = typer.Argument(..., help="A run folder holding the record (record.mcap)."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON document on stdout."),
    acceptance: Path | None = typer.Option(None, "--acceptance", help="Take the baseline from this record instead."),
) -> None:
    """Read a record, find drift and faults against the acceptance baseline, name probable causes."""
    from cellguard.diagnose.from_record import diagnose_record

    try:
        diagnosis = diagnose_record(folder, acceptance=acceptance)
    except CellguardError as exc:
        fail(exc)
    if as_json:
        sys.stdout.write(json.dumps(diagnosis.to_dict()) + "\n")
        return
    _print_diagnosis(diagnosis)


@app.command()
def report(
    folder: Path = typer.Argument(..., help="A run folder holding the record (record.mcap)."),
    out: Path | None = typer.Option(None, "-o", "--out", help="HTML file to write (default FOLDER/report.html)."),
) -> None:
    """Write a self-contained HTML report: timeline, last good versus faulted, drift, asymmetry, context."""
    from cellguard.report.from_record import write_report

    try:
        path = write_report(folder, out)
    except CellguardError as exc:
        fail(exc)
    Console().print(f"report: {path}")


@app.command("train-demo-policy")
def train_demo_policy(
    out: Path = typer.Option(Path("demo-policy.onnx"), "--out", "-o", help="ONNX file to write."),
    cycles: int = typer.Option(10, min=2, max=500, help="Scripted demonstration cycles to record."),
    random_features: int = typer.Option(64, min=0, max=4096, help="Random tanh units beside the time basis."),
    seed: int = typer.Option(0, help="Seed of the demonstrations and the initial weights."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON document on stdout."),
) -> None:
    """Clone the scripted arm program into a small MLP on the CPU; run it with `policy: onnx:FILE`."""
    from dataclasses import asdict

    from cellguard.policy.bc import train_demo_policy as train

    try:
        report = train(out, cycles=cycles, random_features=random_features, seed=seed)
    except CellguardError as exc:
        fail(exc)
    if as_json:
        sys.stdout.write(json.dumps(asdict(report)) + "\n")
        return
    Console().print(f"trained on {report.samples} samples from {report.cycles} cycles in {report.seconds:.0f} s "
                    f"({report.hidden} hidden units, joint error rms {report.rms_error_mrad:.2f} mrad, "
                    f"worst {report.max_error_mrad:.2f} mrad); "
                    f"written to {report.path}; run it with policy: onnx:{report.path}")


def _print_diagnosis(d) -> None:
    console = Console(highlight=False)
    data = d.to_dict()
    console.print(f"diagnosis: {data['cycles']} cycles, baseline {data['baseline_cycles']}, "
                  f"{len(data['drift_alarms'])} drift alarm(s), last good cycle {data['last_good_cycle']}, "
                  f"first faulted cycle {data['first_faulted_cycle']}", markup=False)
    if not d.findings:
        console.print("  no fault found", markup=False)
    for f in d.findings:
        joints = f" ({', '.join(f.joints)})" if f.joints else ""
        console.print(f"  {f.cause}{joints} from cycle {f.cycle}, confidence {f.confidence:.2f}", markup=False)
        for line in f.evidence:
            console.print(f"    - {line}", markup=False)


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


def _record_figures(quick: bool) -> dict:
    from cellguard.record.bench import figures

    return figures(quick=quick)


def _guard_figures(quick: bool) -> dict:
    from cellguard.control.bench import figures

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
