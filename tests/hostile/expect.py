"""What every hostile case must show: the documented exit code, one error line, no traceback, nothing earlier changed."""

from __future__ import annotations

import hashlib
from pathlib import Path

from typer.testing import CliRunner

from cellguard.cli import app

runner = CliRunner()


def snapshot(folder: Path) -> dict[str, str]:
    """sha256 of every file under ``folder`` by relative path: compared before and after a hostile call."""
    folder = Path(folder)
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def refused(args: list[str], code: int = 2, contains: str = "") -> str:
    """Run the CLI with ``args``; assert exit ``code``, exactly one ``error:`` line on stderr and no traceback."""
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == code, (result.exit_code, result.stdout, result.stderr, result.exception)
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    assert "Traceback" not in result.stdout + result.stderr
    assert contains in lines[0], lines[0]
    return lines[0]
