"""``cellguard train-demo-policy`` refuses, in one line and before any demonstration is recorded, a seed past the
range numpy is seeded with and an ``-o`` in a folder no file can be made in; a link to a folder is followed (and a
link to nothing makes its target where it points, as every output does: tests/test_output_links.py)."""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cellguard.cli import app

runner = CliRunner()
QUICK = ["--cycles", "2", "--random-features", "0"]


def _train(out: Path, *args: str) -> subprocess.CompletedProcess:
    """500 demonstration cycles take minutes: a refusal that comes after them misses the timeout."""
    return subprocess.run([sys.executable, "-c", "from cellguard.cli import app; app()", "train-demo-policy",
                           "--cycles", "500", "-o", str(out), *args], capture_output=True, text=True, timeout=60)


def _refused(done: subprocess.CompletedProcess, starts: str) -> None:
    assert done.returncode == 2 and done.stdout == "", done.stderr
    assert done.stderr.startswith(starts) and done.stderr.count("\n") == 1, done.stderr


@pytest.mark.parametrize("seed", [2**32, 2**64, 10**30])
def test_a_seed_past_2_to_the_32_is_refused_naming_the_option_and_its_range(tmp_path, seed):
    out = tmp_path / "p.onnx"
    result = runner.invoke(app, ["train-demo-policy", *QUICK, "-o", str(out), "--seed", str(seed)])
    assert result.exit_code == 2 and result.stdout == ""
    assert result.stderr == f"error: --seed: must be in 0..4294967295, got {seed}\n"
    assert not out.exists()


def test_the_last_seed_of_the_range_trains(tmp_path):
    out = tmp_path / "p.onnx"
    result = runner.invoke(app, ["train-demo-policy", *QUICK, "-o", str(out), "--seed", str(2**32 - 1)])
    assert result.exit_code == 0, result.output
    assert out.stat().st_size > 1000


def test_a_link_to_a_folder_that_is_there_is_followed(tmp_path):
    (tmp_path / "real").mkdir()
    (tmp_path / "models").symlink_to(tmp_path / "real")
    result = runner.invoke(app, ["train-demo-policy", *QUICK, "-o", str(tmp_path / "models" / "model.onnx")])
    assert result.exit_code == 0, result.output
    assert [p.name for p in (tmp_path / "real").iterdir()] == ["model.onnx"]


def _read_only_folder(tmp_path: Path) -> Path:
    """A folder this process cannot make a file in: one of mode 0o555, or, for root (who writes there all the same),
    sysfs."""
    folder = tmp_path / "read-only"
    folder.mkdir()
    folder.chmod(0o555)
    for candidate in (folder, Path("/sys")):
        try:
            with tempfile.TemporaryFile(dir=candidate):
                pass
        except OSError:
            return candidate
    pytest.skip("no folder here refuses this user a new file")


def test_an_output_in_a_read_only_folder_is_refused_before_the_training(tmp_path):
    """It failed only at the save, one line but after every demonstration was recorded and fit."""
    folder = _read_only_folder(tmp_path)
    out = folder / "cellguard-model.onnx"
    _refused(_train(out), f"error: -o {out}: cannot write in {folder} (")
    assert not out.exists()


def test_an_output_that_is_a_folder_is_refused(tmp_path):
    _refused(_train(tmp_path), f"error: -o {tmp_path}: is a folder; name a file to write\n")
