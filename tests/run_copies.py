"""Shared by the output tests: one real run per module, copied for each test, and a small real disk."""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
from pathlib import Path

import pytest

from cellguard.runtime import run_scenario
from cellguard.scenario import parse_scenario


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A real run long enough to be its own baseline, so that ``report`` gets as far as writing."""
    out = tmp_path_factory.mktemp("outputs") / "run"
    run_scenario(parse_scenario({"cell": "arm-pick-place", "seed": 5, "acceptance_cycles": 5,
                                 "production_cycles": 1}), out)
    return out


@pytest.fixture
def run(recorded, tmp_path):
    """A copy of the run for each test: a command that wrongly writes into it spoils no other test."""
    return Path(shutil.copytree(recorded, tmp_path / "run"))


@contextlib.contextmanager
def small_tmpfs(folder: Path, size: str):
    """``folder`` as a tmpfs of ``size`` (``64k``, ``4m``) while the block runs; the test skips where it cannot be
    mounted (not root)."""
    if os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs needs root")
    folder.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(folder)],
                      capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs here")
    try:
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], check=False)
