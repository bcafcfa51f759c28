"""The console script's usage errors are one line, exit 2, as bad input is everywhere else: an option's value of the
wrong type or out of its range, an unknown option or command, a missing argument. The parser drew each in a box of
four to six lines ("Usage: ... Try ... --help ... ╭─ Error ─╮ ..."), and the same command refused --seed in one
line and --cycles in a box. A command's own exit code still comes through."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(sys.executable).with_name("cellguard")  # the console script installed beside this Python
pytestmark = pytest.mark.skipif(not SCRIPT.is_file(), reason="the cellguard console script is not installed here")


def cellguard(*args: str, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run([str(SCRIPT), *args], capture_output=True, text=True, timeout=120, cwd=cwd)


@pytest.mark.parametrize(("args", "says"), [
    (("train-demo-policy", "-o", "a.onnx", "--cycles", "1"), "error: Invalid value for '--cycles': "),
    (("sim-server", "arm-pick-place", "--port", "abc"), "error: Invalid value for '--port': "),
    (("demo", "--bogus"), "error: No such option: --bogus"),
    (("record", "info"), "error: Missing argument "),
    (("nosuchcommand",), "error: No such command 'nosuchcommand'."),
    (("embodiment", "show", "--profile"), "error: Option '--profile' requires an argument."),
])
def test_a_usage_error_is_one_line_and_exit_2(tmp_path, args, says):
    result = cellguard(*args, cwd=tmp_path)
    assert (result.returncode, result.stdout) == (2, ""), result
    assert len(result.stderr.splitlines()) == 1 and result.stderr.startswith(says), result.stderr
    assert "--help` says how" in result.stderr
    assert not (tmp_path / "a.onnx").exists()


def test_help_and_a_commands_own_exit_code_come_through(tmp_path):
    shown = cellguard("--help")
    assert shown.returncode == 0 and "Usage: cellguard" in shown.stdout
    refused = cellguard("record", "info", str(tmp_path / "none"))  # the command's own refusal: typer.Exit(2)
    assert (refused.returncode, refused.stderr) == (2, f"error: {tmp_path / 'none'}: no record here\n")


@pytest.mark.parametrize("group", [(), ("record",), ("fleet",)])
def test_a_group_called_bare_prints_its_help_and_nothing_else(group):
    result = cellguard(*group)
    assert (result.returncode, result.stderr) == (2, "") and "Usage: cellguard" in result.stdout, result
