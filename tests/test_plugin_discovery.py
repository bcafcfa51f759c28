"""A stray or broken file in a plugin package (fault kinds, process changes, recovery behaviours, gate metrics) is
one line naming it, exit 2, or is not imported at all. Discovery runs while cellguard is imported: a scratch module
missing a dependency, a file with a syntax error or an editor's copy of a kind (``friction_step copy.py``, which
defined its kind a second time) ended every command, ``--help`` included, in a traceback (exit 1).

The command line runs in a fresh process whose plugin package is found on a temporary folder more, as if the files
were in it, before anything imports it."""

from __future__ import annotations

import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

import cellguard.robot.faults
import cellguard.robot.faults.friction_step
from cellguard.plugins import PluginError, discover

# python -c CLI PACKAGE FOLDER ARGS...: the console script (cellguard.entry:main) with PACKAGE's path extended
CLI = """
import importlib.machinery, sys

package, folder = sys.argv.pop(1), sys.argv.pop(1)


class Extend:
    def find_spec(self, name, path=None, target=None):
        if name != package:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        spec.submodule_search_locations.append(folder)
        return spec


sys.meta_path.insert(0, Extend())
from cellguard.entry import main
main()
"""
MISSING = "import not_installed_pkg  # an optional dependency this machine lacks\n"


def _cellguard(package: str, folder: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", CLI, package, str(folder), *args], capture_output=True, text=True,
                          timeout=300, cwd=folder)


@pytest.mark.parametrize(("package", "args"), [
    ("cellguard.robot.faults", ["--help"]),
    ("cellguard.robot.process", ["--help"]),
    ("cellguard.robot.recovery", ["--help"]),
    ("cellguard.release.metrics", ["release", "status", "--site", "no-site"]),  # imported by the commands using it
])
def test_a_module_that_cannot_be_imported_ends_the_command_in_one_line_naming_it(tmp_path, package, args):
    (tmp_path / "scratch.py").write_text(MISSING)
    done = _cellguard(package, tmp_path, *args)
    assert (done.returncode, done.stdout) == (2, "")
    assert done.stderr == (f"error: {tmp_path / 'scratch.py'}: cannot be imported: ModuleNotFoundError: "
                           f"No module named 'not_installed_pkg'\n")


def test_copies_helpers_and_sub_packages_beside_the_kinds_are_not_imported(tmp_path):
    shipped = Path(cellguard.robot.faults.__file__).with_name("friction_step.py").read_text()
    for copy in ("friction_step copy.py", "friction_step-old.py", "friction_step.py~", "friction_step.py.orig"):
        (tmp_path / copy).write_text(shipped)  # imported, each would define friction_step a second time
    (tmp_path / "_shared.py").write_text(MISSING)
    (tmp_path / "helpers").mkdir()
    (tmp_path / "helpers" / "__init__.py").write_text(MISSING)
    done = _cellguard("cellguard.robot.faults", tmp_path, "--help")
    assert (done.returncode, done.stderr) == (0, "") and "Usage:" in done.stdout
    (tmp_path / "friction_step_old.py").write_text(shipped)  # a name that can be a module's is one
    done = _cellguard("cellguard.robot.faults", tmp_path, "--help")
    assert (done.returncode, done.stderr) == (2, (
        f"error: {tmp_path / 'friction_step_old.py'}: fault kind 'friction_step' is defined twice: "
        f"cellguard.robot.faults.friction_step.FrictionStep ({cellguard.robot.faults.friction_step.__file__}) and "
        f"cellguard.robot.faults.friction_step_old."
        f"FrictionStep\n"))


@pytest.mark.parametrize(("source", "cause"), [
    ("def f(:\n", "SyntaxError: invalid syntax (wip.py, line 1)"),
    ("raise SystemExit('not a plugin')\n", "SystemExit: not a plugin"),  # a script without a __main__ guard
    ("raise RuntimeError('one\\n  two')\n", "RuntimeError: one two"),  # one line whatever the message
])
def test_any_failure_to_import_is_one_error_naming_the_module_and_why(tmp_path, monkeypatch, source, cause):
    package = tmp_path / tmp_path.name  # a package name of its own: each case's found on its own folder
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "wip.py").write_text(source)
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(PluginError, match=f"^{re.escape(str(package / 'wip.py'))}: cannot be imported: "
                                          f"{re.escape(cause)}$"):
        discover(package.name, [str(package)], lambda module: (), "plugin")


@pytest.mark.parametrize("diagnosis", ["rebsae", ""])
def test_a_process_change_whose_diagnosis_is_no_way_of_conditioning_is_refused_naming_it(tmp_path, diagnosis):
    """Misspelt or left out, its declarations were silently not conditioned on: a declared heavier gripper
    diagnosed as a load change."""
    (tmp_path / "new_gripper.py").write_text(textwrap.dedent(f'''
        from typing import ClassVar, Literal

        from cellguard.robot.process.base import ProcessChange


        class NewGripper(ProcessChange):
            kind: Literal["new_gripper"]
            diagnosis: ClassVar[str] = "{diagnosis}"
    '''))
    refused = (f"error: {tmp_path / 'new_gripper.py'}: process change kind cellguard.robot.process.new_gripper."
               f"NewGripper: diagnosis {diagnosis!r} is not one of 'rebase', 'settle'\n")
    done = _cellguard("cellguard.robot.process", tmp_path, "diagnose", "no-run")  # imports the diagnosis
    assert (done.returncode, done.stderr) == (2, refused)
    # the drift gate metric imports it too: the error is the process change's, not "drift.py cannot be imported"
    done = _cellguard("cellguard.robot.process", tmp_path, "release", "status", "--site", "no-site")
    assert (done.returncode, done.stderr) == (2, refused)


def test_a_kind_pydantic_cannot_build_and_a_message_with_escapes_are_one_printable_line(tmp_path):
    """A field naming a type that does not exist imported fine, then failed every scenario in a traceback (used
    or not); a plugin's message is the plugin's text: its escape codes are shown, never sent to the terminal."""
    (tmp_path / "nudge.py").write_text(textwrap.dedent('''
        from typing import Literal

        from cellguard.robot.faults.base import Fault


        class Nudge(Fault):
            kind: Literal["nudge"]
            how: "NudgeShape | None" = None
    '''))
    done = _cellguard("cellguard.robot.faults", tmp_path, "--help")
    assert done.returncode == 2 and done.stderr.startswith(
        f"error: {tmp_path / 'nudge.py'}: fault kind cellguard.robot.faults.nudge.Nudge: ") and \
        "NudgeShape" in done.stderr and done.stderr.count("\n") == 1, done.stderr
    (tmp_path / "nudge.py").write_text("raise RuntimeError('bad \\x1b[31mred\\x07')\n")
    done = _cellguard("cellguard.robot.faults", tmp_path, "--help")
    assert (done.returncode, done.stderr) == (
        2, f"error: {tmp_path / 'nudge.py'}: cannot be imported: RuntimeError: bad \\x1b[31mred\\x07\n")
