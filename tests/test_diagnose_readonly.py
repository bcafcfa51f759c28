"""A record on read-only storage (an archive) is diagnosed, reported and pushed: baseline.json and fixes.json are not
rewritten when they already hold what the diagnosis would write, and one that cannot be written is one warning line
each (exit 1), the diagnosis still printed and used. Before, every command ended with `error: fixes DIR/fixes.json:
cannot write (Read-only file system)`, exit 2, though the file held exactly what would have been written."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.runtime import run_scenario
from cellguard.scenario import parse_scenario

runner = CliRunner()
CACHES = ("baseline.json", "fixes.json")


@pytest.fixture(scope="module")
def diagnosed(tmp_path_factory) -> Path:
    """A real run, diagnosed once where it was written: its baseline.json and fixes.json are current."""
    out = tmp_path_factory.mktemp("readonly") / "run"
    run_scenario(parse_scenario({"cell": "arm-pick-place", "seed": 5, "acceptance_cycles": 5,
                                 "production_cycles": 1}), out)
    result = runner.invoke(app, ["diagnose", str(out), "--no-fleet", "--json"])
    assert result.exit_code == 0, result.output
    assert all((out / name).is_file() for name in CACHES)
    return out


@contextlib.contextmanager
def read_only(folder: Path):
    """``folder`` seen through a read-only bind mount (EROFS, which root meets too) while the block runs; the test
    skips where it cannot be mounted (not root, no right to mount)."""
    if os.geteuid() != 0:
        pytest.skip("a read-only bind mount needs root")
    view = folder.with_name(f"{folder.name}-ro")
    view.mkdir()
    if subprocess.run(["mount", "--bind", str(folder), str(view)], capture_output=True).returncode:
        pytest.skip("cannot bind-mount here")
    try:
        if subprocess.run(["mount", "-o", "remount,ro,bind", str(view)], capture_output=True).returncode:
            pytest.skip("cannot remount read-only here")
        yield view
    finally:
        subprocess.run(["umount", str(view)], check=False)


def _copy(diagnosed: Path, tmp_path: Path, without: tuple[str, ...] = ()) -> Path:
    run = Path(shutil.copytree(diagnosed, tmp_path / "run"))
    for name in without:
        (run / name).unlink()
    return run


def _policy(tmp_path: Path) -> Path:
    policy = tmp_path / "policy.yaml"
    policy.write_text("tenant: ta\nsite: s1\nexport: signatures\n")
    return policy


def _read_by_three_commands(ro: Path, tmp_path: Path):
    """``diagnose``, ``report`` (to a page elsewhere) and ``fleet push`` (without a store) of the record at ``ro``."""
    return (runner.invoke(app, ["diagnose", str(ro), "--no-fleet", "--json"]),
            runner.invoke(app, ["report", str(ro), "--no-fleet", "-o", str(tmp_path / "page.html")]),
            runner.invoke(app, ["fleet", "push", str(ro), "--policy", str(_policy(tmp_path)), "--site-dir",
                                str(tmp_path / "site")]))


def test_an_archived_record_with_current_files_is_diagnosed_reported_and_pushed(diagnosed, tmp_path):
    run = _copy(diagnosed, tmp_path)
    before = {name: (run / name).read_bytes() for name in CACHES}
    with read_only(run) as ro:
        diagnose, report, push = _read_by_three_commands(ro, tmp_path)
    assert diagnose.exit_code == 0, diagnose.output
    assert json.loads(diagnose.stdout)["baseline_cycles"] == 5
    assert report.exit_code == 0 and (tmp_path / "page.html").is_file(), report.output
    assert push.exit_code == 0, push.output
    assert {name: (run / name).read_bytes() for name in CACHES} == before


def test_files_that_cannot_be_written_are_one_warning_each_and_the_diagnosis_stands(diagnosed, tmp_path):
    run = _copy(diagnosed, tmp_path, without=CACHES)
    with read_only(run) as ro:
        diagnose, report, push = _read_by_three_commands(ro, tmp_path)
    assert diagnose.exception is None or isinstance(diagnose.exception, SystemExit), diagnose.output
    assert diagnose.exit_code == 1, diagnose.output
    assert json.loads(diagnose.stdout)["baseline_cycles"] == 5  # the diagnosis, printed whole
    warnings = [line for line in diagnose.stderr.splitlines() if line.startswith("warning: ")]
    assert len(warnings) == 2, diagnose.stderr
    for line, name in zip(warnings, CACHES):
        assert f"{ro / name}: cannot write (Read-only file system)" in line, line
    assert report.exit_code == 1 and (tmp_path / "page.html").is_file(), report.output
    assert push.exit_code == 1 and "fleet push:" in push.stdout and "fixes.json" in push.stderr, push.output
    assert not any((run / name).exists() for name in CACHES)


def test_a_writable_record_is_not_rewritten_unchanged(diagnosed, tmp_path):
    run = _copy(diagnosed, tmp_path)
    inodes = {name: (run / name).stat().st_ino for name in CACHES}
    result = runner.invoke(app, ["diagnose", str(run), "--no-fleet", "--json"])
    assert result.exit_code == 0, result.output
    assert {name: (run / name).stat().st_ino for name in CACHES} == inodes  # a write renames a new file in


def test_fleet_similar_of_an_archived_record_warns_of_the_files_it_cannot_keep(diagnosed, tmp_path):
    """`fleet similar RUN` diagnoses the run as push does: it ended `error: ... cannot write`, exit 2. The store is
    asked only for the run's findings, and this run has none, so an unreachable one is not contacted."""
    run = _copy(diagnosed, tmp_path, without=CACHES)
    policy = _policy(tmp_path)
    store = "host=127.0.0.1 port=1 dbname=x user=x password=x"
    with read_only(run) as ro:
        similar = runner.invoke(app, ["fleet", "similar", str(ro), "--policy", str(policy), "--store", store,
                                      "--json"])
    assert similar.exception is None or isinstance(similar.exception, SystemExit), similar.output
    assert similar.exit_code == 1, similar.output
    assert json.loads(similar.stdout) == {"findings": []}
    assert [line.startswith("warning: ") for line in similar.stderr.splitlines()] == [True, True], similar.stderr
