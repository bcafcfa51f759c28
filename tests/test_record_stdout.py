"""``record info`` and ``record query`` when stdout cannot take their output: a full disk (``> /dev/full``) was a
Rich traceback, a closed stdout (``>&-``) an AttributeError traceback. Now one line on stderr and exit 2."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
from record_synth import record


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("stdout") / "run"
    record(folder, 2, 200)
    return folder


COMMANDS = [["record", "info"], ["record", "info", "--json"], ["record", "query", "SELECT * FROM cycles"]]


def _cellguard(args: list[str], stdout) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", "from cellguard.cli import app; app()", *args], stdout=stdout,
                          stderr=subprocess.PIPE, text=True, timeout=120)


def _with_folder(command: list[str], folder) -> list[str]:
    return [*command[:2], str(folder), *command[2:]]


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full")
@pytest.mark.parametrize("command", COMMANDS)
def test_a_full_stdout_is_one_line_and_exit_2(run_dir, command):
    with open("/dev/full", "w") as full:
        result = _cellguard(_with_folder(command, run_dir), full)
    assert result.returncode == 2, result.stderr
    assert result.stderr == "error: stdout: cannot write the output (No space left on device)\n"


@pytest.mark.parametrize("command", COMMANDS)
def test_a_closed_stdout_is_one_line_and_exit_2(run_dir, command):
    args = [sys.executable, "-c", "import os, sys; os.close(1); from cellguard.cli import app; sys.stdout = None; "
            "app()", *_with_folder(command, run_dir)]
    result = subprocess.run(args, stderr=subprocess.PIPE, text=True, timeout=120)
    assert result.returncode == 2, result.stderr
    assert result.stderr == "error: stdout: cannot write the output (stdout is closed)\n"
