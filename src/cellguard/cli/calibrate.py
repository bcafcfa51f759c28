"""``cellguard excite``, ``identify`` and ``replay``: measure the robot's model from its own record, and
check a hypothesis about an incident in the calibrated simulator."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from cellguard.cli import stdout
from cellguard.cli.app import app
from cellguard.cli.errors import exit_if_stopped, fail
from cellguard.cli.text import say
from cellguard.errors import CellguardError


@app.command()
def excite(
    target: str = typer.Argument(..., help="A registered cell name or a scenario YAML file (its robot and guard)."),
    seconds: float = typer.Option(30.0, "--seconds", help="Length of the excitation \\[s]."),
    out: Path = typer.Option(..., "--out", help="Folder for the record (every tick) and summary.json."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a record already in --out."),
    stand: bool = typer.Option(False, "--stand", help="A legged robot held on a stand, feet in the air (a simulated "
                               "cell is mounted; the record says so, and identify then fits its joints)."),
) -> None:
    """Run a persistently exciting trajectory inside the profile's limits through the guard, and record it."""
    from cellguard.calibrate.excitation import BASE_HZ, FADE_S, excitation_scenario
    from cellguard.calibrate.excitation import excite as run_excitation
    from cellguard.errors import ScenarioError
    from cellguard.scenario import load_scenario

    # past the fade-in, half a base period turns even the slowest harmonic, so every joint's velocity takes both signs
    # at full swing (friction told from damping): at 1 s, in the fade-in, damping came out 6.7 standard errors off
    shortest = FADE_S + 0.5 / BASE_HZ
    try:
        if not shortest <= seconds <= 3600.0:
            raise ScenarioError(f"--seconds: {seconds:g} is outside {shortest:g}..3600 s (the fade-in, then half the "
                                "slowest harmonic's period: a shorter record fits friction and damping wrong)")
        base = load_scenario(Path(target)) if target.endswith((".yaml", ".yml")) else target
        from cellguard.calibrate.stand import Stand

        summary = run_excitation(excitation_scenario(base, seconds), out, overwrite=overwrite,
                                 stand=Stand() if stand else None)
        stdout.written(f"the record in {out}")
    except CellguardError as exc:
        fail(exc)
    exit_if_stopped(summary, out)  # a stopped excitation is a record to read, not one to identify from unread
    interventions = [e for e in summary["events"] if not e["kind"].startswith(("approach", "retreat"))]
    say(f"{out}: {seconds:g} s of excitation recorded; {len(interventions)} guard events", err=False)


@app.command()
def identify(
    records: list[Path] = typer.Argument(..., help="Record folders (full-rate ticks with motor current)."),
    params: str | None = typer.Option(None, "--params", help="Comma-separated, of friction, armature, damping, kp, "
                                      "delay, payload (default: every one the model has)."),
    cell_name: str = typer.Option("", "--cell", help="The robot the model is of (default: the first record's)."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON document on stdout."),
    write: Path | None = typer.Option(None, "--write", help="Update this profile's measured friction, damping and "
                                      "armature and write a calibrated MJCF beside it (a new calibration version; the "
                                      "old profile kept beside it; a link: the file it points to). A scenario's "
                                      "calibration: PROFILE runs with it."),
    only: list[str] = typer.Option([], "--only", help="JOINT,PARAM: re-fit just this (friction, damping or armature "
                                   "of one joint; repeatable) with every other term held at the profile's values "
                                   "(--write's profile, else the cell's): what the residual monitor said drifted."),
) -> None:
    """Fit the cell's MuJoCo model (from its nominal MJCF) to recorded ticks: value, unit, 95 % interval
    (simultaneous over all the parameters reported). Exit 1 (one warning line each) when a record is not whole
    (--write then refuses: a calibration is stored only from whole records), and when --write's fit has a
    friction, damping or armature below zero (reported, not written)."""
    from cellguard.calibrate.identify import CalibrationError, load_records, negative_values, parse_params, record_robot
    from cellguard.calibrate.identify import identify as fit
    from cellguard.cli.record import warn_if_damaged
    from cellguard.record.outputs import refuse_output
    from cellguard.robot.registry import make_cell

    try:
        if only and params is not None:
            raise CalibrationError("--params: not with --only, which re-fits just the JOINT,PARAM it names; "
                                   "give one of the two")
        if write is not None:  # the profile is read and rewritten: never a record, nor a file in a run folder
            for record in records:
                refuse_output(write, record, option="--write")
        cell = make_cell(cell_name or record_robot(records[0]))
        if write is not None:  # not a kept copy, and the names it adds beside it, before the fit (a name too long
            # failed after it)
            from cellguard.calibrate.write import check_write_target

            check_write_target(write, cell)
        basis = None  # the profile --only holds its other terms at: --write refuses it if it changed meanwhile
        if only:
            from cellguard.calibrate.identify import parse_only, refit
            from cellguard.calibrate.torque_model import JointTerms
            from cellguard.errors import ProfileError
            from cellguard.yaml_file import read_bounded

            pairs = parse_only(only, cell)
            basis = read_bounded(write, "profile", ProfileError) if write is not None else None
            terms = JointTerms.from_profile(cell, write, "--write")
            segments, healths, left_out = load_records(records, cell, write=write is not None)
            _whole_for_write(write, healths)
            result = refit(segments, cell, pairs, terms)
            result["warnings"][:0] = left_out  # ticks the fit went on without, and why
        else:
            wanted = parse_params(params, cell)  # before any record is read
            if write is not None:
                from cellguard.calibrate.write import refuse_dropped_payload

                refuse_dropped_payload(write, cell, wanted)
            segments, healths, left_out = load_records(records, cell, write=write is not None)
            _whole_for_write(write, healths)
            result = fit(segments, cell, wanted)
            result["warnings"][:0] = left_out
        refused = write is not None and bool(negative_values(result["estimates"]))
        if refused:  # reported (the warning names the values), never stored
            result["warnings"].append(f"--write: {write} not written: a friction, damping or armature below zero "
                                      "is no calibration")
        elif write is not None:
            from cellguard.calibrate.identify import measured_on
            from cellguard.calibrate.write import write_profile

            written = write_profile(write, cell, result, measured_on(records), basis)
            stdout.written(f"calibration version {written.version} ({written.profile}, calibrated MJCF "
                           f"{written.mjcf}; the old profile kept as {written.kept})")
            result["profile_version"], result["mjcf"] = written.version, str(written.mjcf)
            result["profile"] = str(written.profile)
    except CellguardError as exc:
        fail(exc)
    damaged = max([warn_if_damaged(health, path) for path, health in healths] + [int(refused)])
    if as_json:
        typer.echo(json.dumps(result, indent=1))
        raise typer.Exit(damaged)
    for warning in result["warnings"]:
        say(f"warning: {warning}")
    say(f"{result['robot']}: {result['samples']} ticks from {len(result['records'])} record(s); intervals "
        f"{result['interval']}", err=False)
    if write is not None and not refused:
        target = "" if result["profile"] == str(write) else f" (the link's target {result['profile']})"
        say(f"{write}{target}: calibration version {result['profile_version']}; calibrated MJCF {result['mjcf']}",
            err=False)
    for e in result["estimates"]:
        name = f"{e['parameter']}" + (f" {e['joint']}" if e["joint"] else "")
        if e["interval"] is None:
            say(f"  {name:24s} not identifiable from this data (nominal {e['nominal']:.4g} {e['unit']})", err=False)
        else:
            lo, hi = e["interval"]
            bias = f", method bias {e['method_bias']:+.2g}" if e.get("method_bias") is not None else ""
            say(f"  {name:24s} {e['value']:.4g} {e['unit']}  [{lo:.4g}, {hi:.4g}]  (nominal {e['nominal']:.4g}"
                f"{bias})", err=False)
    if result.get("payload_held_kg"):
        say(f"  {'payload':24s} {result['payload_held_kg']:.4g} kg held (the calibration's)", err=False)
    raise typer.Exit(damaged)


def _whole_for_write(write: Path | None, healths: list) -> None:
    """--write stores a calibration only from records read whole: a truncated or damaged one is refused."""
    from cellguard.calibrate.identify import CalibrationError

    for path, health in healths:
        if write is not None and not health.ok:
            raise CalibrationError(f"--write: {path} is not whole ({health.describe()}); a calibration is stored "
                                   "only from whole records (identify without --write reports the fit)")


@app.command()
def replay(
    record: Path = typer.Argument(..., help="A record folder or its .mcap file."),
    cycle: int = typer.Option(..., "--cycle", help="The cycle to replay."),
    model: str = typer.Option("calibrated", "--model", help="calibrated (the profile's measured values) or nominal."),
    profile: Path | None = typer.Option(None, "--profile", help="The calibrated profile (identify --write's); "
                                        "default: the one the record was made with (found by its sha256 in the "
                                        "file the run read, or kept beside it; gone, the record's own profile "
                                        "document), else the cell's own. A profile "
                                        "other than the record's is used with a warning naming both."),
    vary: str | None = typer.Option(None, "--vary", help="PARAM:JOINT=LOW..HIGH, e.g. friction:elbow=0.8..1.6: "
                                    "search the factor that best reproduces the recorded cycle."),
    out: Path | None = typer.Option(None, "-o", "--out", help="HTML page (default: replay-cycle-N.html in the "
                                   "record's run folder; needed for an .mcap file outside one, as report's); a file "
                                   "there is replaced only if it is a page cellguard wrote (or empty): never the "
                                   "record, a profile, an MJCF or any other file."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON document on stdout."),
) -> None:
    """Re-run a recorded cycle's chunks in the simulator from its recorded start; overlay simulated and recorded.
    Exit 1 (one warning line) when the record is not whole: what was readable is replayed. A calibrated replay
    with a profile other than the record's says so in one warning line (exit 0: comparing a record against a
    newer calibration is a check of its own)."""
    from cellguard.calibrate.identify import CalibrationError
    from cellguard.calibrate.replay import replay as run_replay
    from cellguard.cli.record import warn_if_damaged
    from cellguard.record.beside import guarded, pinned
    from cellguard.record.outputs import PAGE, refuse_output
    from cellguard.record.writer import REPLAY_PAGES
    from cellguard.report.from_record import report_path
    from cellguard.report.replay import write_replay

    try:
        if profile is not None and model != "calibrated":
            raise CalibrationError(f"--profile: only with --model calibrated; the {model} model reads no profile")
        # a loose .mcap has no run folder: its page beside it would be another loose record's (report refuses too)
        page = out or report_path(record).with_name(f"replay-cycle-{cycle}.html")
        # before the simulation: never over the record, its run folder's files, the --profile read, nor any file
        # but a page (the profile replay reads is found by its sha256 wherever the run read it: no list names it)
        refuse_output(page, record, inputs=[("--profile file", profile)], own=(REPLAY_PAGES,), kind=PAGE)
        with pinned(record, "replayed") as pin:  # nothing beside a record replaced meanwhile (``record.beside``)
            result = run_replay(record, cycle, model=model, profile=profile, vary=vary)
            with guarded(pin, page, "replayed"):
                write_replay(result, page, record)
        stdout.written(f"the replay page {page}")
    except CellguardError as exc:
        fail(exc)
    d = result.to_dict()
    d["page"] = str(page)
    damaged = warn_if_damaged(result.rc.health, record) if result.rc.health is not None else 0
    if result.profile.note is not None:
        say(f"warning: {result.profile.note}")
    if as_json:
        typer.echo(json.dumps(d, indent=1))
        raise typer.Exit(damaged)
    say(f"{record}: cycle {cycle} replayed in the {result.profile.model(result.model)}: {d['ticks']} ticks, "
        f"mean current NRMSE {d['mismatch']['cost']:.4f}", err=False)
    if result.vary is not None:
        v = result.vary
        say(f"  {v.parameter} of {v.joint} x {result.best:.3f} reproduces it best (searched {v.low:g}..{v.high:g})",
            err=False)
    say(f"  {page}", err=False)
    raise typer.Exit(damaged)
