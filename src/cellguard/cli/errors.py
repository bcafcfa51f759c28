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


def exit_if_stopped(summary: dict, out: Path) -> None:
    """A run the loop stopped (record failure, robot link fault, overrun budget): one line on stderr and exit 1;
    stopped by the operator (Ctrl-C, SIGTERM): one line and exit 130; a record that failed only at its close (its
    summary or its index could not be written: the cycles ran, the record is not whole): one line and exit 1."""
    from cellguard.runtime.operator_stop import by_operator

    stopped = summary.get("stopped")
    if by_operator(stopped):
        failed = summary.get("record_failed")
        fail(OperatorStopped(f"{stopped}; the record in {out} " + (f"is not whole ({failed}): `cellguard record "
                                                                   f"recover` writes a finished copy" if failed
                                                                   else "is complete")))
    if stopped:
        causes = [e["kind"] for e in summary["events"]  # the cause, not the stop carrying it out
                  if e.get("category") is not None and e["kind"] not in STOP_EFFECTS]
        # the one ``stopped`` names (a stale state, then the server gone: the first); else the last
        kind = next((k for k in causes if k in stopped), causes[-1] if causes else "stop")
        sys.stderr.write(f"error: {printable(f'the cell was stopped ({kind}): {stopped}')}; "
                         f"{printable(out / 'summary.json')} says what ran\n")
        raise typer.Exit(1)
    failed = summary.get("record_failed")
    if failed:
        sys.stderr.write(f"error: {printable(f'the record in {out} failed at its close: {failed}')}; "
                         f"`cellguard record recover {printable(out)} -o NEW_DIR` writes a finished copy with its "
                         f"index\n")
        raise typer.Exit(1)
