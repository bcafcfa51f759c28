"""The console script's own output goes through the stdout guard as every command's does: ``cellguard --help`` and a
bare ``cellguard`` (help printed by the parser before any command's guard was set) ended a full stdout in a
traceback and a closed one in exit 0. Now each is one line and exit 2, and a reader that stops early 141, as
``cellguard record --help`` already was."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

SCRIPT = [sys.executable, "-c", "from cellguard.entry import main; main()"]  # what the console script runs
HELPS = [["--help"], [], ["record", "--help"], ["demo", "--help"], ["record", "query", "--help"]]


@pytest.mark.parametrize("args", HELPS)
def test_help_to_a_full_stdout_is_one_line_and_exit_2(args):
    with open("/dev/full", "w") as full:
        done = subprocess.run(SCRIPT + args, stdout=full, stderr=subprocess.PIPE, text=True, timeout=120)
    assert (done.returncode, done.stderr) == (2, "error: stdout: cannot write the output (No space left on device)\n")


@pytest.mark.parametrize("args", HELPS[:2])
def test_help_to_a_closed_stdout_is_one_line_and_exit_2(args):
    done = subprocess.run(SCRIPT + args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, timeout=120,
                          preexec_fn=lambda: os.close(1))
    assert (done.returncode, done.stderr) == (2, "error: stdout: cannot write the output (stdout is closed)\n")


@pytest.mark.parametrize("args", HELPS[:2])
def test_help_to_a_reader_that_stopped_ends_quietly_with_141(args):
    proc = subprocess.Popen(SCRIPT + args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    proc.stdout.close()  # gone before the help is written
    assert (proc.wait(timeout=120), proc.stderr.read()) == (141, "")


def test_help_to_a_good_stdout_is_printed_and_exit_0():
    done = subprocess.run(SCRIPT + ["--help"], capture_output=True, text=True, timeout=120)
    assert (done.returncode, done.stderr) == (0, "") and "Usage: " in done.stdout
