"""Checks on what a CLI command printed, shared by the CLI tests."""

from __future__ import annotations


def one_error(result) -> str:
    """The one ``error:`` line of a typer CliRunner result that exited 2 without a traceback."""
    assert result.exception is None or isinstance(result.exception, SystemExit), result.output
    assert result.exit_code == 2, result.output
    lines = result.output.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.output
    return lines[0]
