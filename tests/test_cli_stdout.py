"""A stdout that cannot be written (full, closed) ends every command in one line and exit 2; a reader that
stopped early ends it with 141 (diagnose, report, fleet audit and release status gave tracebacks)."""

from __future__ import annotations

import subprocess
import sys

import pytest

CLI = [sys.executable, "-c", "from cellguard.cli import app; app()"]


@pytest.mark.parametrize("args", [["embodiment", "show", "arm-pick-place"], ["embodiment", "show", "quadruped-turns", "--json"]])
def test_a_full_or_closed_stdout_is_one_line_and_exit_2(args):
    with open("/dev/full", "w") as full:
        done = subprocess.run(CLI + args, stdout=full, stderr=subprocess.PIPE, text=True, timeout=120)
    assert done.returncode == 2 and done.stderr == "error: stdout: cannot write the output (No space left on device)\n"
    closed = subprocess.run(CLI + args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, timeout=120,
                            preexec_fn=lambda: __import__("os").close(1))
    assert closed.returncode == 2 and closed.stderr == "error: stdout: cannot write the output (stdout is closed)\n"


def test_a_reader_that_stops_early_ends_the_command_with_141():
    proc = subprocess.Popen(CLI + ["embodiment", "show", "arm-pick-place", "--json"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    proc.stdout.close()  # gone before the command writes
    assert proc.wait(timeout=120) == 141 and proc.stderr.read() == ""


def test_a_run_whose_stdout_fails_after_its_record_is_written_exits_1_saying_it_is_kept(tmp_path):
    """Exit 2 says nothing was done; the run's record was there, whole."""
    scenario = tmp_path / "s.yaml"
    scenario.write_text("cell: arm-pick-place\nseed: 3\nacceptance_cycles: 0\nproduction_cycles: 1\n")
    with open("/dev/full", "w") as full:
        done = subprocess.run(CLI + ["run", str(scenario), "--out", str(tmp_path / "out")], stdout=full,
                              stderr=subprocess.PIPE, text=True, timeout=300)
    assert done.returncode == 1, done.stderr
    assert done.stderr.splitlines()[-1] == (f"error: stdout: cannot write the output (No space left on device); the "
                                            f"record in {tmp_path / 'out'} is written and kept")
    assert subprocess.run(CLI + ["record", "info", str(tmp_path / "out")], capture_output=True).returncode == 0


def test_a_closed_descriptor_is_held_so_no_file_the_command_opens_takes_its_number(tmp_path):
    """With stdout closed, the first file a command opened got descriptor 1: a child process inherited it as its
    stdout, and the guard's end put /dev/null over it."""
    probe = ("import os; from cellguard.cli import stdout; stdout.guard(); "
             f"fd = os.open({str(tmp_path / 'f')!r}, os.O_WRONLY | os.O_CREAT); os.write(2, str(fd).encode())")
    done = subprocess.run([sys.executable, "-c", probe], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                          timeout=120, preexec_fn=lambda: (__import__("os").close(0), __import__("os").close(1)))
    assert done.returncode == 0 and int(done.stderr) > 2, done.stderr
