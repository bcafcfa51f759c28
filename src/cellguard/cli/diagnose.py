"""`cellguard diagnose` and `cellguard report`: read a record, name causes, write the HTML page."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import typer
from rich.console import Console

from cellguard.cli import stdout
from cellguard.cli.app import app
from cellguard.cli.errors import fail
from cellguard.cli.record import recover_hint, warn_if_damaged
from cellguard.cli.text import printable_tree, say
from cellguard.errors import CellguardError, ConfigError, RecordError

FLEET_HELP = ("Add what fixed each cause at other sites (the fleet store, as CELLGUARD_FLEET_DSN's tenant); "
              "default: when that is set.")


@app.command()
def diagnose(
    folder: Path = typer.Argument(..., help="A run folder holding the record (record.mcap), or that record.mcap."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON document on stdout."),
    acceptance: Path | None = typer.Option(None, "--acceptance", help="Take the baseline from this record instead."),
    fleet: bool | None = typer.Option(None, "--fleet/--no-fleet", help=FLEET_HELP),
) -> None:
    """Read a record, find drift and faults against the acceptance baseline, name probable causes."""
    from cellguard.diagnose.from_record import BASELINE_FILE, diagnose_record, run_folder
    from cellguard.record.json_values import plain

    try:
        beside = run_folder(folder)  # where fixes.json (and the record's own baseline) are written; None: nowhere
        baseline_was = _file_version(beside / BASELINE_FILE) if beside is not None else None
        unkept: list[str] = []
        diagnosis = diagnose_record(folder, acceptance=acceptance, fleet=fleet_advice(fleet), unkept=unkept)
        if beside is not None and not unkept:
            new = _file_version(beside / BASELINE_FILE) != baseline_was  # written only when none fit
            stdout.written(f"the diagnosis in {beside} ({'baseline.json, ' if new else ''}fixes.json)")
        health = record_health(folder)
        baseline_health = record_health(acceptance) if acceptance is not None else None
    except CellguardError as exc:
        fail(_with_health(exc, folder))
    out = diagnosis.to_dict()
    out["record"] = {"ok": health.ok, "status": health.describe(), **out["record"]}
    if baseline_health is not None:
        out["acceptance_record"] = {"ok": baseline_health.ok, "status": baseline_health.describe()}
    if as_json:  # a stdout that cannot take it (`| head`, full, closed) ends the command: cli.stdout
        sys.stdout.write(json.dumps(plain(out), allow_nan=False) + "\n")  # strict JSON: a missing value is null
    else:
        print_diagnosis(diagnosis)
    raise typer.Exit(max(_warn(health, folder, baseline_health, acceptance), warn_of_diagnosis(diagnosis),
                         warn_if_unkept(unkept)))


@app.command()
def report(
    folder: Path = typer.Argument(..., help="A run folder holding the record (record.mcap), or that record.mcap."),
    out: Path | None = typer.Option(None, "-o", "--out", help="HTML file to write (default FOLDER/report.html); a "
                                   "file there is replaced only if it is a page cellguard wrote (or empty)."),
    acceptance: Path | None = typer.Option(None, "--acceptance", help="Take the baseline from this record instead."),
    fleet: bool | None = typer.Option(None, "--fleet/--no-fleet", help=FLEET_HELP),
) -> None:
    """Write a self-contained HTML report: timeline, last good versus faulted, drift, asymmetry, context."""
    from cellguard.diagnose.from_record import diagnose_record
    from cellguard.record.beside import pinned
    from cellguard.record.outputs import PAGE, refuse_output
    from cellguard.record.writer import RECORD_FILE
    from cellguard.report.from_record import REPORT_FILE, report_path, write_report

    try:
        with pinned(folder, "reported") as pin:  # before the first read: nothing goes beside a record replaced since
            health = record_health(folder)
            out = out or report_path(folder)
            # FOLDER/report.html, named or not, is the one file a report writes in a run folder
            refuse_output(out, folder, own=(REPORT_FILE,), kind=PAGE)
            if health.writing and (out.resolve().parent / RECORD_FILE).exists():  # it said "still being written"
                raise RecordError(f"{folder}: still being written by {health.writing}; a report beside it would "
                                  "describe a part of it: give -o FILE outside the run folder, or report once the "
                                  "run has ended")
            baseline_health = record_health(acceptance) if acceptance is not None else None
            unkept: list[str] = []
            diagnosis = diagnose_record(folder, acceptance=acceptance, fleet=fleet_advice(fleet), unkept=unkept,
                                        pin=pin)
            path = write_report(folder, out, diagnosis=diagnosis, health=health, pin=pin)
        stdout.written(path)
    except CellguardError as exc:
        fail(_with_health(exc, folder))
    say(f"report: {path}", err=False)
    raise typer.Exit(max(_warn(health, folder, baseline_health, acceptance), warn_of_diagnosis(diagnosis),
                         warn_if_unkept(unkept)))


def _warn(health, folder: Path, baseline_health, acceptance: Path | None) -> int:
    """One warning line per record that is not whole, the diagnosed one and the ``--acceptance`` one
    whose cycles made the baseline; exit code 1 if either is not whole."""
    code = warn_if_damaged(health, folder)
    if baseline_health is not None:
        code = max(code, warn_if_damaged(baseline_health, acceptance))
    return code


def warn_of_diagnosis(d) -> int:
    """The warning lines of diagnosis ``d`` itself (``warn_if_unsteady``, ``warn_if_from_start``,
    ``warn_if_unexplained_stop``), each once; the exit code: 1 if any, else 0."""
    return max(warn_if_unsteady(d.baseline), warn_if_from_start(d), warn_if_unexplained_stop(d))


def warn_if_from_start(d) -> int:
    """One warning line when the first finding was there in the record's own acceptance cycles (its baseline holds
    the fault, and no cycle is a good one); the exit code: 1 then, else 0, as for an unsteady acceptance."""
    if d.from_start is None:
        return 0
    say(f"warning: baseline: {d.from_start} (--acceptance DIR)")
    return 1


def warn_if_unexplained_stop(d) -> int:
    """One warning line when the run ended in a stop no finding begun by then explains (an operator's stop, a
    killed process need none: ``run_end.NOT_THE_CELL``); the exit code: 1 then, else 0: a run stopped by its cell is
    never "no fault found" and exit 0."""
    from cellguard.diagnose.run_end import explained

    if explained(d.findings, d.run_end):
        return 0
    say(f"warning: the run ended in a stop no finding explains ({d.run_end.words()}): its safety events say "
        "what the guard saw")
    return 1


def warn_if_unsteady(baseline) -> int:
    """One warning line when features trended over the acceptance cycles (a fault already under way: the
    baseline holds part of it); the exit code: 1 then, else 0."""
    from cellguard.diagnose.diagnosis import trend_words

    if not baseline.trends:
        return 0
    say(f"warning: baseline: the acceptance cycles were not steady ({trend_words(baseline, sorted(baseline.trends))}); "
        "changes read against it are too small and may have begun before production: take the baseline from a "
        "steady record with --acceptance DIR")
    return 1


def warn_if_unkept(unkept: list[str]) -> int:
    """One warning line per file beside the record that could not be written (read-only storage); the exit code: 1
    then, else 0. The diagnosis stands: each is made again from the record when missing or out of date."""
    for line in unkept:
        say(f"warning: {line} (the diagnosis stands without it)")
    return 1 if unkept else 0


def fleet_advice(use: bool | None) -> list[dict]:
    """The fleet's fixes per cause, within the caller's rights; a store that is down is a warning only."""
    dsn = os.environ.get("CELLGUARD_FLEET_DSN")
    if use is False or (use is None and not dsn):
        return []
    if not dsn:
        raise ConfigError("--fleet: set CELLGUARD_FLEET_DSN to your tenant's credentials")
    from cellguard.fleet.advice import fleet_fixes
    from cellguard.fleet.store import StoreUnavailable, TenantStore

    try:
        return fleet_fixes(TenantStore(dsn))
    except StoreUnavailable as exc:
        say(f"warning: no advice from the fleet: {exc}")
        return []


def _with_health(exc: CellguardError, folder: Path) -> CellguardError:
    """``exc`` saying also what the record's health says where the record was cut short: a run killed after 2 of 5
    acceptance cycles read only "baseline: needs at least 5 acceptance cycles, got 2", a live one "no production
    cycles", where `record info` said truncated (and `recover`) or still being written."""
    try:
        health = record_health(folder)
    except CellguardError:  # the record itself is the error (missing, foreign, unreadable): said already
        return exc
    if not (health.truncated or health.writing):  # damage within a whole record: the error names what it lacks
        return exc
    if health.writing and str(health.writing) in str(exc):  # the refusal of a live record says so itself
        return exc
    exc.args = (f"{exc} (the record is {health.describe()}{recover_hint(health, folder)})",)
    return exc


def record_health(folder: Path):
    """What a full read of the record finds (truncation, damaged chunks, a lost context)."""
    from cellguard.record.reader import open_record

    with open_record(folder) as rec:
        return rec.health()


def print_diagnosis(d) -> None:
    from cellguard.diagnose.diagnosis import FROM_START, no_tick_words, unwatched_words
    from cellguard.diagnose.run_end import CUT_SHORT

    console = Console(highlight=False)
    data = printable_tree(d.to_dict())  # joint and signal names come from the record
    good, bad = data["last_good_cycle"], data["first_faulted_cycle"]
    none_before = FROM_START if data["present_from_start"] else "no good cycle before it"
    faulted = ("" if bad is None else f", first faulted cycle {bad} ({none_before})" if good is None
               else f", last good cycle {good}, first faulted cycle {bad}")
    console.print(f"diagnosis: {data['cycles']} cycles, baseline {data['baseline_cycles']}, "
                  f"{len(data['drift_alarms'])} drift alarm(s){faulted}", markup=False)
    end = data["run_end"]
    if end is not None:  # the operator's stop, a policy lost, a killed process: named, with its cycle and category
        console.print(f"  the run ended: {d.run_end.words()}", markup=False)
    if not data["findings"]:
        stopped = end is not None and end["needs_cause"]
        console.print("  no cause found for the stop that ended the run" if stopped else "  no fault found",
                      markup=False)
    for f in data["findings"]:
        joints = f" ({', '.join(f['joints'])})" if f.get("joints") else ""
        console.print(f"  {f['cause']}{joints} from cycle {f['cycle']}, confidence {f['confidence']:.2f}", markup=False)
        for line in f["evidence"]:
            console.print(f"    - {line}", markup=False)
    if d.slip_gone is not None:
        console.print(f"  note: {d.slip_gone.words()}", markup=False)
    if d.cut_short:
        console.print(f"  note: cycle {', '.join(map(str, d.cut_short))} {CUT_SHORT}", markup=False)
    if d.unwatched:
        console.print(f"  note: {unwatched_words(d.unwatched, d.cycles)}", markup=False)
    if d.no_tick_features:
        console.print(f"  note: {no_tick_words(d.no_tick_features, d.cycles)}", markup=False)
    if data.get("recoveries"):
        tally: dict[tuple[str, str], int] = {}
        for r in data["recoveries"]:
            tally[r["behaviour"], r["outcome"]] = tally.get((r["behaviour"], r["outcome"]), 0) + 1
        cycles = len({r["cycle"] for r in data["recoveries"]})
        console.print(f"  recoveries: {len(data['recoveries'])} attempt(s) in {cycles} cycle(s): " + ", ".join(
            f"{b} {o} {n}" for (b, o), n in sorted(tally.items())), markup=False)


def _file_version(path: Path) -> tuple[int, int] | None:
    """(inode, modification time) of ``path``, None if there is none: a file written beside and renamed differs."""
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_ino, st.st_mtime_ns
