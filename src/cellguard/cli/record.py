"""``cellguard record``: look into a fault record, export its ticks, recover a damaged one, query the index.

Exit codes: 0 the record is complete, or still being written by its run with nothing lost so far (a note says
so); 1 it was read but is truncated or damaged (the message says what was recovered); 2 bad input or nothing
readable, and `record recover` of a record still being written; 141 (quietly) when `record query`'s reader closed
the pipe before the last row.
"""

from __future__ import annotations

import json
import sys
from collections import Counter
from pathlib import Path

import typer
from rich.console import Console

from cellguard.cli.app import app
from cellguard.cli.errors import fail
from cellguard.cli.stdout import require_open
from cellguard.cli.text import printable_tree, say
from cellguard.control.events import EventKind
from cellguard.errors import CellguardError, RecordError

record_app = typer.Typer(no_args_is_help=True, help="Read, export, recover and query fault records.")
app.add_typer(record_app, name="record")


def warn_if_damaged(health, folder: Path) -> int:
    """Print one warning line saying what was lost (stderr); the exit code: 0 complete, 1 truncated or damaged.
    A record still being written with nothing lost so far is no damage: one note, 0 (it read as truncated, 1)."""
    if health.ok:
        return 0
    if health.writing and health.intact:
        say(f"note: {folder}: {health.describe()}; read it again once its run has ended for the whole record")
        return 0
    say(f"warning: {folder}: {health.describe()}{recover_hint(health, folder)}")
    return 1


def recover_hint(health, folder: Path) -> str:
    """How to get a finished copy of a record not whole, where ``record recover`` can make one ("": none)."""
    if health.recoverable and not health.writing:
        return f"; `cellguard record recover {folder} -o NEW_DIR` writes a finished copy"
    return ""


@record_app.command()
def info(
    folder: Path = typer.Argument(..., help="Run folder (holding record.mcap) or the .mcap file."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON document on stdout."),
) -> None:
    """Context, time span, cycles, events and the health of a record."""
    from cellguard.record.reader import open_record

    try:
        with open_record(folder) as rec:
            health = rec.health()
            contexts = rec.contexts
            cycles = list(rec.cycles())
            events = list(rec.events())
            marked = rec.cycle_spans()  # an older recorder stamped a lost run with a cycle whose begin it never wrote
    except CellguardError as exc:
        fail(exc)
    context = contexts[0].context if contexts else {}
    doc = {
        "file": str(rec.file), "record_id": rec.record_id, "record_version": rec.version,
        "start_utc": rec.start_utc,
        "health": {"ok": health.ok, "status": health.describe(), "finished": health.finished,
                   "truncated": health.truncated, "damage": list(health.damage), "context_loss": health.context_loss,
                   "recovered_from": health.recovered, "writing": health.writing},
        "span_s": None if health.span_ns is None else [health.span_ns[0] * 1e-9, health.span_ns[1] * 1e-9],
        "messages": health.messages,
        "context": {k: context.get(k) for k in ("site", "cell_id", "cell", "policy", "embodiment", "fixture_datum",
                                                 "envelope", "software")},
        "context_changes": [{"t_s": c.t_ns * 1e-9, "version": c.version, "changed": list(c.changed)}
                            for c in contexts[1:]],
        "cycles": {phase: {"cycles": sum(c.phase == phase for c in cycles),
                           "succeeded": sum(c.success for c in cycles if c.phase == phase)}
                   for phase in ("acceptance", "production")},
        "events": dict(Counter(e.kind for e in events)),
        "stops": [{"t_s": e.t_ns * 1e-9, "kind": e.kind, "category": e.category, "reason": e.reason}
                  for e in events if e.category is not None],
        "run_lost": [{"t_s": e.t_ns * 1e-9, "cycle": e.cycle if e.cycle in marked else None, "reason": e.reason}
                     for e in events if e.kind == EventKind.RUN_PROCESS_LOST],
    }
    if as_json:
        sys.stdout.write(json.dumps(doc, indent=1, default=str) + "\n")
    else:
        _print_info(doc)
    raise typer.Exit(warn_if_damaged(health, folder))


def _print_info(doc: dict) -> None:
    doc = printable_tree(doc)  # the record's text (site, policy source, reasons) may hold escape codes
    out = Console(highlight=False, soft_wrap=True)
    ctx = doc["context"]
    policy, emb = ctx.get("policy") or {}, ctx.get("embodiment") or {}
    out.print(f"record   {doc['file']}  [{doc['health']['status']}]", markup=False)
    run = doc["record_id"] or "no run id"  # format 1 has none
    out.print(f"run      {run}  started {doc['start_utc']}  (record format {doc['record_version']})",
              markup=False)
    out.print(f"site     {ctx.get('site')} / {ctx.get('cell_id')} ({ctx.get('cell')})", markup=False)
    out.print(f"policy   {policy.get('source')}  sha256 {str(policy.get('sha256'))[:12]}", markup=False)
    calibration = emb.get("calibration") or {}  # the dates of measured values are not a calibration
    calibrated = (f"calibration {calibration.get('version')} ({calibration.get('date')})" if calibration
                  else "calibration none")
    out.print(f"profile  {emb.get('robot')} {emb.get('version')}  sha256 {str(emb.get('sha256'))[:12]}  "
              f"{calibrated}; measured {', '.join(emb.get('calibration_dates') or []) or 'never'}", markup=False)
    out.print(f"datum    {ctx.get('fixture_datum')}", markup=False)
    if doc["span_s"]:
        out.print(f"span     {doc['span_s'][0]:.3f} s to {doc['span_s'][1]:.3f} s", markup=False)
    for phase, stats in doc["cycles"].items():
        out.print(f"{phase:<12} {stats['cycles']} cycles, {stats['succeeded']} succeeded", markup=False)
    out.print(f"events   {sum(doc['events'].values())}: "
              + ", ".join(f"{k} {v}" for k, v in sorted(doc["events"].items())), markup=False)
    for stop in doc["stops"]:
        out.print(f"stop     t={stop['t_s']:.3f} s {stop['kind']} (category {stop['category']}): {stop['reason']}",
                  markup=False)
    for lost in doc["run_lost"]:
        when = (f" in cycle {lost['cycle']}" if lost["cycle"] is not None  # only what the record marks
                else " between cycles" if any(stats["cycles"] for stats in doc["cycles"].values()) else "")
        out.print(f"ended    t={lost['t_s']:.3f} s{when}, not by the run: {lost['reason']}", markup=False)
    for change in doc["context_changes"]:
        out.print(f"context  changed at t={change['t_s']:.3f} s: {', '.join(change['changed'])}", markup=False)


@record_app.command()
def export(
    folder: Path = typer.Argument(..., help="Run folder (holding record.mcap) or the .mcap file."),
    fmt: str = typer.Option("csv", "--format", help="csv or parquet."),
    output: Path = typer.Option(..., "-o", "--output", help="File to write; a file there is replaced only if it is "
                                "an export of that format cellguard wrote (or empty)."),
    rate: str = typer.Option("all", "--rate", help="all (full rate where kept, else decimated), decimated, full."),
    cycle: int | None = typer.Option(None, "--cycle", help="Only this cycle."),
) -> None:
    """Ticks as rows: t_ns, cycle, joint, q_ref, q_cmd, q_meas, qd_meas, effort, current."""
    from cellguard.record.export import OWN_KINDS, check_format, write_ticks
    from cellguard.record.outputs import refuse_output
    from cellguard.record.reader import RATES, open_record

    try:
        if rate not in RATES:  # the reader's own refusal names its parameter, "rate:"
            raise RecordError(f"--rate: {rate!r} is not one of {', '.join(RATES)}")
        if cycle is not None and not 0 <= cycle < 2**63:
            raise RecordError(f"--cycle: {cycle} is outside [0, 2^63); cycles are numbered from 0")
        # first: a record or a run's file there is the graver mistake; an unknown --format is refused next
        refuse_output(output, folder, kind=OWN_KINDS.get(fmt))
        check_format(output, fmt)
        with open_record(folder) as rec:
            rows = write_ticks(rec, output, fmt, rate=rate, cycle=cycle)
            health = rec.health()
    except CellguardError as exc:
        fail(exc)
    say(f"{rows} rows written to {output}")
    raise typer.Exit(warn_if_damaged(health, folder))


@record_app.command("to-lerobot")
def to_lerobot(
    folder: Path = typer.Argument(..., help="Run folder (holding record.mcap) or the .mcap file."),
    output: Path = typer.Option(..., "-o", "--output", help="New folder for the dataset."),
    fps: int | None = typer.Option(None, "--fps", help="Frames per second; must divide the record's decimated rate "
                                   "(default: that rate, 50 Hz at most servo rates)."),
    task: str | None = typer.Option(None, "--task", help="Task string of every episode: one line, not blank "
                                    "(default: the cell's name)."),
    success_only: bool = typer.Option(False, "--success-only", help="Only cycles that succeeded."),
) -> None:
    """Cycles as a LeRobotDataset v3 (one episode per cycle): state, action sent, camera readings, task."""
    from cellguard.record.outputs import refuse_output
    from cellguard.record.lerobot_export import export_lerobot
    from cellguard.record.reader import open_record

    try:
        refuse_output(output, folder, to_folder=True)
        with open_record(folder) as rec:
            result = export_lerobot(rec, output, fps=fps, task=task, success_only=success_only)
            health = rec.health()
    except CellguardError as exc:
        fail(exc)
    for why in result.skipped:
        say(f"skipped {why}")
    say(f"{len(result.episodes)} episodes, {result.frames} frames at {result.fps} fps written to {output}")
    raise typer.Exit(warn_if_damaged(health, folder))


@record_app.command()
def recover(
    folder: Path = typer.Argument(..., help="Run folder (holding record.mcap) or the .mcap file."),
    output: Path = typer.Option(..., "-o", "--output", help="New folder for the recovered record and index."),
) -> None:
    """Copy every readable chunk into a finished file with a fresh summary, and rebuild the index."""
    from cellguard.record.outputs import refuse_output
    from cellguard.record.recovery import recover as run_recover

    try:
        refuse_output(output, folder, to_folder=True)
        health = run_recover(folder, output)
    except CellguardError as exc:
        fail(exc)
    say(f"source {health.describe()}; recovered record written to {output}")


@record_app.command()
def query(
    folder: Path = typer.Argument(..., help="Run folder holding index/ (or its record.mcap, or the index folder)."),
    sql: str = typer.Argument(..., help="One read-only DuckDB SELECT over the tables `cycles` and `events`; SQL "
                              "that starts with '-' (a -- comment) goes after '--': record query FOLDER -- SQL."),
    timeout_s: float = typer.Option(60.0, "--timeout", help="Stop a query still running after this many seconds."),
) -> None:
    """Run one SELECT on the per-cycle index, read-only and confined to it; one JSON object per row on stdout."""
    from cellguard.record.query import json_line, run_query

    try:
        require_open()  # closed: refused before the query starts
        names, rows = run_query(folder, sql, timeout_s)
        try:  # a stdout that fails ends the command (cli.stdout): the query is stopped first
            for row in rows:
                sys.stdout.write(json_line(names, row) + "\n")
            sys.stdout.flush()
        finally:
            rows.close()
    except CellguardError as exc:
        fail(exc)
