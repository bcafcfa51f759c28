"""`cellguard embodiment`: the profiles of the registered cells."""

from __future__ import annotations

import json
import sys
from decimal import ROUND_CEILING, ROUND_FLOOR, Decimal
from pathlib import Path

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
    profile_path: Path | None = typer.Option(None, "--profile", help="A profile file of this cell's robot (e.g. "
                                             "one identify --write calibrated), checked against its model and "
                                             "its profile: the same joints and symmetry (order and limits may "
                                             "differ). Default: the cell's own."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON document on stdout."),
) -> None:
    """Print a cell's embodiment profile: joints and limits with their units, measured parameters (as written, when
    and how), symmetry pairs and the calibration. Limits are SI, shown rounded inward; with --json the limits are
    SI and each measured value is in the unit it names (as written in the profile)."""
    from cellguard.embodiment import load_profile
    from cellguard.embodiment.profile import OtherRobot, mismatch
    from cellguard.errors import ProfileError
    from cellguard.robot.registry import make_cell

    try:
        robot = make_cell(cell)
        try:
            profile = (robot.profile if profile_path is None
                       else load_profile(robot.model, profile_path, robot.profile.robot))
        except OtherRobot as exc:
            raise ProfileError(f"--profile: {exc}") from None
        # a run's check but for order and limits (a profile of this robot, shown as replay runs one): an extra
        # joint or another symmetry was shown, exit 0, and refused by a run only
        why = mismatch(profile, robot.profile, exact=False)
        if why is not None:
            raise ProfileError(f"--profile: {profile_path} {why}")
    except CellguardError as exc:
        fail(exc)
    if as_json:
        sys.stdout.write(json.dumps(profile.to_dict(), indent=1) + "\n")
        return
    print_profile(profile)


def print_profile(profile) -> None:
    """The profile as tables, SI with units: joints and limits, measured parameters (as written, with when and
    how), symmetry pairs, and the calibration. Text from the profile file is printed as it is (no markup)."""
    from rich.text import Text

    from cellguard.cli.text import printable
    from cellguard.embodiment.profile import SI_UNITS

    def cell(value: object) -> Text:
        return Text(printable(value))

    console = Console(highlight=False)
    console.print(cell(f"{profile.robot} (profile {profile.version})"))
    for kind in ("hinge", "slide"):
        joints = [j for j in profile.joints if j.kind == kind]
        if not joints:
            continue
        u = SI_UNITS[kind]
        table = _table(f"{kind} joints")
        table.add_column("joint", no_wrap=True)
        for key, label in (("position", "position"), ("velocity", "velocity"), ("acceleration", "accel."),
                           ("jerk", "jerk"), ("effort", "effort"), ("torque_constant", "Kt")):
            table.add_column(Text(f"{label}\n[{u[key]}]"), justify="right", no_wrap=True)  # Text: no markup
        for j in joints:
            position = f"{_inward(j.position[0], up=True)}..{_inward(j.position[1], up=False)}"
            maxima = (_inward(x, up=False) for x in (j.velocity, j.acceleration, j.jerk, j.effort))
            table.add_row(*map(cell, (j.name, position, *maxima, f"{j.torque_constant:g}")))
        console.print(table)
    measured = _table("measured")
    for col in ("joint", "parameter", "value", "measured", "method"):
        measured.add_column(col, no_wrap=col in ("joint", "value", "measured"), overflow="fold")
    for m in profile.measured:
        measured.add_row(*map(cell, (m.joint, m.parameter, m.as_written, m.measured, m.method)))
    console.print(measured if profile.measured else cell("measured: none"))
    if profile.symmetry:
        pairs = _table("symmetry (q_right = sign * q_left)")
        for col in ("left", "right", "sign"):
            pairs.add_column(col)
        for pair in profile.symmetry:
            pairs.add_row(*map(cell, (pair.left, pair.right, f"{pair.sign:+g}")))
        console.print(pairs)
    else:
        console.print(cell("symmetry: none"))
    console.print(cell(_calibration(profile)))


def _calibration(profile) -> str:
    """Where the profile's measured values come from: its calibration, else typed in, or identified by an older
    identify --write (it wrote no calibration block: such a profile read as typed in)."""
    from cellguard.calibrate.write import IDENTIFIED  # here: identification imports scipy (a second of every command)

    c = profile.calibration
    if c is not None:
        return (f"calibration: {c.version} of {c.date} from {', '.join(c.records)} (MJCF {c.mjcf}, "
                f"replaced {c.previous})")
    if any(m.method.startswith(IDENTIFIED) for m in profile.measured):
        return ("calibration: none stated (measured values name an identification: an older identify --write, "
                "which wrote no calibration block)")
    return "calibration: none (the measured values were typed in)"


def _inward(value: float, up: bool, digits: int = 4) -> str:
    """``value`` to ``digits`` significant digits, rounded up (a lower limit) or down (an upper one): a limit
    shown rounded outward (1.6581 as 1.66) claimed a range the guard does not allow."""
    exact = Decimal(repr(value))
    if not exact:
        return "0"
    step = Decimal(1).scaleb(exact.adjusted() - digits + 1)
    return f"{float(exact.quantize(step, rounding=ROUND_CEILING if up else ROUND_FLOOR)):g}"


def _table(title: str):
    """A table narrow enough for an 80-column terminal: rules under the header only, single spaces between."""
    from rich import box
    from rich.table import Table

    return Table(title=title, box=box.SIMPLE_HEAD, pad_edge=False, collapse_padding=True)
