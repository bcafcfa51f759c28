"""`cellguard run` and `cellguard demo`: a scenario through the tick path, and the main job."""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from cellguard.cli import stdout
from cellguard.cli.app import app
from cellguard.cli.diagnose import print_diagnosis
from cellguard.cli.errors import exit_if_stopped, fail, record_in
from cellguard.cli.text import printable, say
from cellguard.errors import CellguardError, OutputError
from cellguard.output import make_folder
from cellguard.record import folder_lock
from cellguard.scenario import Scenario, load_scenario

err = Console(stderr=True)
DEMO_SCENARIO = Path(__file__).parents[1] / "scenarios" / "demo.yaml"


def _run(scenario: Scenario, out: Path, quiet: bool, realtime: bool = False, overwrite: bool = False,
         lock: int | None = None) -> dict:
    from cellguard.calibrate.residual import watch_scenario
    from cellguard.record.writer import refuse_existing
    from cellguard.runtime import Run, run_scenario

    refuse_existing(out, overwrite)  # a run never overwrites a record unless asked
    replacing = replaces(out, overwrite)
    run = Run(scenario, realtime=realtime)  # every check (cell, faults, policy) before anything is created or printed
    try:
        watch_scenario(run)
    except BaseException:
        run.close()
        raise
    created = not out.exists()
    # no markup: "arm-pick-place [acceptance]" would lose its phase as an unknown tag
    progress = Progress(TextColumn("{task.description}", markup=False), BarColumn(), MofNCompleteColumn(),
                        TimeElapsedColumn(), console=err, disable=quiet, transient=False)
    task = progress.add_task(f"{scenario.cell} cycles", total=scenario.total_cycles)

    def advance(outcome: dict) -> None:
        progress.start()  # shown from the first cycle on: an error while the record starts is one line alone
        progress.update(task, advance=1, description=f"{scenario.cell} [{outcome['phase']}]")

    try:
        summary = run_scenario(scenario, out, on_cycle=advance, overwrite=overwrite, run=run, lock=lock)
        stdout.written(f"the record in {out}")
        return summary
    except BaseException as exc:
        if run.recording is None:  # refused before the record started: leave no empty folder behind
            _remove_if_empty(out, created)
            raise
        rec = run.recording
        left = _record_left(rec, out, replacing)
        if isinstance(exc, OutputError) and (rec.finished or rec.failed):  # the record closed; summary.json failed
            progress.stop()  # its last line before the error's
            sys.stderr.write(f"error: {printable(f'{exc}; {left}')}\n")
            raise typer.Exit(1) from None
        if isinstance(exc, CellguardError):
            raise CellguardError(f"{exc}; {left}") from exc
        say(f"error: {left}")  # then the traceback, or Ctrl-C's line
        raise
    finally:
        if progress.live.is_started:  # stopping one never shown prints a blank line on a pipe
            progress.stop()


def replaces(out: Path, overwrite: bool) -> bool:
    """Whether a run into ``out`` replaces a record already there (--overwrite): once the new record has started,
    the old one is gone, however the run ends."""
    from cellguard.record.writer import RECORD_FILE

    return overwrite and (out / RECORD_FILE).exists()


def _record_left(rec, out: Path, replaced: bool) -> str:
    """What a run that raised left in ``out``, by how its record closed (a start-up refusal mid-tick closes it
    whole, and was called partial), and whether its summary.json was written (a third Ctrl-C as the run closed
    raised after it: the line said it had none); ``replaced``: its record took the place of one already there
    (--overwrite), which the line did not say (a start-up refusal left only its ``startup_refused`` event)."""
    record = record_in(out, replaced)
    if rec.finished and (out / "summary.json").is_file():
        return f"{record} is finished and whole, its summary.json written"
    if rec.finished:
        return f"{record} is finished and whole; it has no summary.json"
    if rec.failed:
        return f"{record} failed ({rec.failed}); it has no summary.json"
    return f"{record} is partial (no summary.json)"


def _print_summary(summary: dict, out: Path, as_json: bool) -> None:
    if as_json:
        extra = {k: summary[k] for k in ("timing", "stopped") if k in summary}
        sys.stdout.write(json.dumps({"out": str(out), "phases": summary["phases"],
                                     "events": len(summary["events"]), **extra}) + "\n")
        return
    for phase, stats in summary["phases"].items():
        if stats["cycles"]:
            say(f"{phase}: {stats['cycles']} cycles, success {stats['success_rate']:.0%}", err=False)
    say(f"events: {len(summary['events'])}; written to {out}", err=False)  # as given: "[/]" is a folder name here


def _warn_short_acceptance(scenario: Scenario, summary: dict) -> None:
    """Say so when a run that ran its course cannot serve as its own baseline: what diagnose and report would
    refuse (too few acceptance cycles in all, or of one motion of a cell that alternates them), in their words,
    with the scenario's count. A stopped run says why it stopped, in its own line (its record is partial anyway)."""
    from cellguard.diagnose.baseline import too_few
    from cellguard.diagnose.cycles import as_cycles

    if summary.get("stopped"):
        return
    why = too_few(as_cycles(c for c in summary["cycles"] if c.get("phase") == "acceptance"))
    if why is not None:
        sys.stderr.write(f"warning: baseline: {why} (the scenario's acceptance_cycles: {scenario.acceptance_cycles}); "
                         f"give diagnose and report --acceptance OTHER_RUN\n")


@app.command()
def run(
    scenario: Path = typer.Argument(..., help="Scenario YAML file."),
    out: Path = typer.Option(..., "--out", help="Folder for the record and summary.json."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON document on stdout."),
    realtime: bool = typer.Option(False, "--realtime", help="Run a simulated cell on wall time (a bridge always is)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a record already in --out (never by default)."),
) -> None:
    """Run a scenario file on its simulated cell or robot bridge (the robot picks the clock)."""
    replaced = replaces(out, overwrite)
    try:
        sc = load_scenario(scenario)
        summary = _run(sc, out, quiet=as_json, realtime=realtime, overwrite=overwrite)
    except CellguardError as exc:
        fail(exc)
    _print_summary(summary, out, as_json)
    _warn_short_acceptance(sc, summary)
    exit_if_stopped(summary, out, replaced)


@contextmanager
def _held(out: Path, overwrite: bool) -> Iterator[int | None]:
    """``out`` made and locked (``folder_lock``) for what the command writes there, once ``refuse_existing`` lets
    it (a folder inside another run's was made before the refusal); a folder it made and left empty is removed
    again."""
    from cellguard.record.writer import refuse_existing

    refuse_existing(out, overwrite)
    created = not out.exists()
    folder = make_folder(out, "--out")
    try:
        lock = folder_lock.hold(folder, wait_s=folder_lock.BRIEF_S)  # a report writing beside a record is waited on
    except BaseException:
        _remove_if_empty(folder, created)
        raise
    try:
        yield lock
    except BaseException:
        _remove_if_empty(folder, created)
        raise
    finally:
        folder_lock.release(lock)


def _remove_if_empty(folder: Path, created: bool) -> None:
    if created and folder.is_dir() and not any(folder.iterdir()):
        folder.rmdir()


@app.command()
def demo(
    out: Path = typer.Option(Path("cellguard-demo"), "--out", help="Folder for the demo's outputs."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON document on stdout."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a record already in --out (never by default)."),
) -> None:
    """Acceptance then a production shift with site drift on the simulated arm cell."""
    from cellguard.diagnose.from_record import diagnose_record
    from cellguard.report.from_record import write_report

    try:
        sc = load_scenario(DEMO_SCENARIO)
        with _held(out, overwrite) as lock:  # until the report is written: a run started there after the record closed had
            # the demo's report, of the demo's record, written beside its own
            replaced = replaces(out, overwrite)
            summary = _run(sc, out, quiet=as_json, overwrite=overwrite, lock=lock)
            exit_if_stopped(summary, out, replaced)  # a stopped shift is not diagnosed, nor one whose record is not whole
            diagnosis = diagnose_record(out)
            report_path = write_report(out, diagnosis=diagnosis)
    except CellguardError as exc:
        fail(exc)
    if as_json:
        sys.stdout.write(json.dumps({"out": str(out), "phases": summary["phases"], "events": len(summary["events"]),
                                     "diagnosis": diagnosis.to_dict(), "report": str(report_path)}) + "\n")
        return
    _print_summary(summary, out, as_json)
    print_diagnosis(diagnosis)
    say(f"report: {report_path}", err=False)
