"""How every command ends on bad input (one line naming what is wrong, exit code 2), on a run the loop stopped
(exit 1) and on the operator's Ctrl-C (exit 130)."""

from __future__ import annotations

import sys
from pathlib import Path

import typer

from cellguard.cli.text import printable
from cellguard.errors import CellguardError, OperatorStopped

INTERRUPTED = 130  # the shell's code for a command ended by Ctrl-C (128 + SIGINT)


def fail(exc: CellguardError) -> None:
    """Print ``error: <message>`` on stderr, on one line with no control characters, and exit 2
    (``stopped by the operator: <message>`` and 130 for an operator stop)."""
    if isinstance(exc, OperatorStopped):
        sys.stderr.write(f"stopped by the operator: {printable(exc)}\n")
        raise typer.Exit(INTERRUPTED)
    sys.stderr.write(f"error: {printable(exc)}\n")
    raise typer.Exit(2)


STOP_EFFECTS = frozenset({"protective_stop", "power_removed", "approach_aborted", "retreat_aborted"})
# with no record, or no link (each link fault's kind is robot_*), the loop moves nothing: no retreat home
NO_RETREAT = ("record_failed", "overrun_budget", "robot_")


def record_in(out: Path, replaced: bool) -> str:
    """How a run's line names its record: ``replaced``, it took the place of one already there (--overwrite), which
    the line did not say (the previous record is gone, however the run ended)."""
    return f"the record in {out}" + (", which replaced the previous one (--overwrite)," if replaced else "")


def exit_if_stopped(summary: dict, out: Path, replaced: bool = False) -> None:
    """A run the loop stopped (record failure, robot link fault, overrun budget): one line on stderr and exit 1;
    stopped by the operator (Ctrl-C, SIGTERM): one line and exit 130; a record that failed only at its close (its
    summary or its index could not be written: the cycles ran, the record is not whole): one line and exit 1. A
    stopped run's line says where the robot was left (``_robot_left``), and its record whether it replaced one
    (``record_in``)."""
    from cellguard.runtime.operator_stop import by_operator

    stopped = summary.get("stopped")
    if by_operator(stopped):
        failed = summary.get("record_failed")
        fail(OperatorStopped(f"{stopped}; {record_in(out, replaced)} " + (f"is not whole ({failed}): `cellguard record "
                                                                   f"recover` writes a finished copy" if failed
                                                                   else "is complete")
                             + f"; {_robot_left(summary)}"))
    if stopped:
        cause = _cause(summary["events"], stopped)
        kind = cause["kind"] if cause else "stop"
        sys.stderr.write(f"error: {printable(f'the cell was stopped ({kind}): {stopped}')}; "
                         f"{printable(_robot_left(summary))}; "
                         f"{printable(out / 'summary.json')} says what ran"
                         + ("; the record replaced the previous one (--overwrite)" if replaced else "") + "\n")
        raise typer.Exit(1)
    failed = summary.get("record_failed")
    if failed:
        sys.stderr.write(f"error: {printable(f'{record_in(out, replaced)} failed at its close: {failed}')}; "
                         f"`cellguard record recover {printable(out)} -o NEW_DIR` writes a finished copy with its "
                         f"index\n")
        raise typer.Exit(1)


def _cause(events: list[dict], stopped: str) -> dict | None:
    """The event that stopped the run, not the stop carrying it out: the one ``stopped`` names (a stale state, then
    the server gone: the first), else the last."""
    causes = [e for e in events if _stops(e)]
    return next((e for e in causes if e["kind"] in stopped), causes[-1] if causes else None)


def _stops(event: dict) -> bool:
    """Whether ``event`` may be why a run stopped: a stop's cause, the safety controller's own protective stop (its
    input has no event of its own: a power-off read "(stop)"), or a retreat not played (no stop at all)."""
    from cellguard.control.checks.safety_input import ASKED_BY_LOOP

    kind, category = event["kind"], event.get("category")
    if kind == "protective_stop":
        return category is not None and not event.get("reason", "").startswith(ASKED_BY_LOOP)
    if kind == "retreat_aborted":
        return category is None
    return category is not None and kind not in STOP_EFFECTS


def _robot_left(summary: dict) -> str:
    """Where a stopped run left the robot, from its last events since any reset: home by its retreat, held away
    from home (a retreat aborted or not played), where the stop left it (power removed, or no motion after a link
    fault or a failed record); with no such event, how far its last measured pose lies from home (``from_home``;
    a summary written before it: home already, or no home pose): the line said only "stopped"."""
    for e in reversed(summary["events"]):
        kind = e["kind"]
        if kind == "reset":  # power came back: what came before does not say where the robot is now
            break
        if kind == "retreat_done":
            return "robot: home (retreat_done)"
        if kind in ("retreat_aborted", "power_removed"):
            where = "held away from home, power on" if kind == "retreat_aborted" else \
                "left where it stopped, power off, not retreated home"
            return f"robot: {where} ({_named(e)})"
        if kind.startswith(NO_RETREAT):
            return f"robot: held where it stopped, not retreated home (no motion after {_named(e)})"
    if "from_home" not in summary:  # an older summary, or a robot never read
        return "robot: no retreat played (home already, or no home pose)"
    far = summary["from_home"]
    if far is None:
        return "robot: no retreat played (no home pose for this robot)"
    said = ", ".join(f"{f['joint']} {_distance(f['distance'], f['unit'])}" for f in far)
    return f"robot: {said} from home (the farthest joint of each unit; no retreat played)"


def _distance(value: float, unit: str) -> str:
    """A joint's distance in its SI unit (rad, m), in thousandths under a tenth: ``1.2 rad``, ``0.3 mrad``, ``under
    0.01 mm`` (6e-06 mm read as a number format, not as home)."""
    if value >= 0.1:
        return f"{value:.3g} {unit}"
    return f"under 0.01 m{unit}" if value < 1e-5 else f"{value * 1e3:.3g} m{unit}"


def _named(event: dict) -> str:
    """An event's kind, and its stop category if it has one."""
    category = event.get("category")
    return event["kind"] + ("" if category is None else f", category {category}")
