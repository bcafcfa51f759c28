"""``cellguard excite`` and ``cellguard identify``: measure the robot's model from its own record."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from cellguard.cli.app import app
from cellguard.cli.errors import fail
from cellguard.errors import CellguardError


@app.command()
def excite(
    target: str = typer.Argument(..., help="A registered cell name or a scenario YAML file (its robot and guard)."),
    seconds: float = typer.Option(30.0, "--seconds", help="Length of the excitation [s]."),
    out: Path = typer.Option(..., "--out", help="Folder for the record (every tick) and summary.json."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a record already in --out."),
) -> None:
    """Run a persistently exciting trajectory inside the profile's limits through the guard, and record it."""
    from cellguard.calibrate.excitation import excitation_scenario
    from cellguard.calibrate.excitation import excite as run_excitation
    from cellguard.errors import ScenarioError
    from cellguard.scenario import load_scenario

    try:
        if not 1.0 <= seconds <= 3600.0:
            raise ScenarioError(f"--seconds: {seconds} is outside 1..3600 s")
        base = load_scenario(Path(target)) if target.endswith((".yaml", ".yml")) else target
        summary = run_excitation(excitation_scenario(base, seconds), out, overwrite=overwrite)
    except CellguardError as exc:
        fail(exc)
    interventions = [e for e in summary["events"] if not e["kind"].startswith(("approach", "retreat"))]
    typer.echo(f"{out}: {seconds:g} s of excitation recorded; {len(interventions)} guard events")


@app.command()
def identify(
    records: list[Path] = typer.Argument(..., help="Record folders (full-rate ticks with motor current)."),
    params: str | None = typer.Option(None, "--params", help="Comma-separated, of friction, armature, damping, kp, "
                                      "delay, payload (default: every one the model has)."),
    cell_name: str = typer.Option("", "--cell", help="The robot the model is of (default: the first record's)."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON document on stdout."),
    write: Path | None = typer.Option(None, "--write", help="Update this profile's measured friction, damping and "
                                      "armature (new version; the old one kept beside it)."),
) -> None:
    """Fit the cell's MuJoCo model (from its nominal MJCF) to recorded ticks: value, unit, 95 % interval."""
    from cellguard.calibrate.identify import identify as fit
    from cellguard.calibrate.identify import load_segments, parse_params, record_robot
    from cellguard.robot.registry import make_cell

    try:
        cell = make_cell(cell_name or record_robot(records[0]))
        wanted = parse_params(params, cell)
        result = fit(load_segments(records, cell), cell, wanted)
        if write is not None:
            import datetime as dt

            from cellguard.calibrate.write import write_profile

            result["profile_version"] = write_profile(write, cell, result, dt.date.today().isoformat())
    except CellguardError as exc:
        fail(exc)
    if as_json:
        typer.echo(json.dumps(result, indent=1))
        return
    if any(e["interval"] is None for e in result["estimates"]):
        typer.echo("warning: some parameters are not excited by these records; `cellguard excite` records a "
                   "trajectory that excites them", err=True)
    typer.echo(f"{result['robot']}: {result['samples']} ticks from {len(result['records'])} record(s)")
    if write is not None:
        typer.echo(f"{write}: version {result['profile_version']}")
    for e in result["estimates"]:
        name = f"{e['parameter']}" + (f" {e['joint']}" if e["joint"] else "")
        if e["interval"] is None:
            typer.echo(f"  {name:24s} not identifiable from this data (nominal {e['nominal']:.4g} {e['unit']})")
        else:
            lo, hi = e["interval"]
            typer.echo(f"  {name:24s} {e['value']:.4g} {e['unit']}  [{lo:.4g}, {hi:.4g}]  (nominal {e['nominal']:.4g})")
