"""``to-lerobot`` into a folder whose name is not UTF-8, and into a mount point: the first ended in pyarrow's
UnicodeEncodeError traceback (its path handling takes UTF-8 only), the second in "cannot write (Invalid cross-device
link)" (the staging folder beside a mount point is on its parent's filesystem, so its parts could not be renamed in)."""

from __future__ import annotations

import json
import os

import pyarrow.parquet as pq
from run_copies import recorded, run, small_tmpfs  # noqa: F401 (fixtures)
from typer.testing import CliRunner

from cellguard.cli import app

runner = CliRunner()


def _export(run, target) -> dict:
    """The dataset ``to-lerobot`` wrote into ``target`` (asserted to exit 0): its info.json."""
    result = runner.invoke(app, ["record", "to-lerobot", str(run), "-o", str(target)])
    assert result.exit_code == 0 and result.exception is None, result.output
    info = json.loads((target / "meta/info.json").read_text())
    with open(target / "data/chunk-000/file-000.parquet", "rb") as f:
        assert pq.read_table(f).num_rows == info["total_frames"] > 0
    return info


def test_a_folder_name_that_is_not_utf8_takes_the_dataset(run, tmp_path):
    parent = tmp_path / os.fsdecode(b"parent\xfa")
    parent.mkdir()
    _export(run, parent / "ds")
    assert sorted(os.listdir(parent)) == ["ds"]  # no staging folder left beside it


def test_a_mount_point_takes_the_dataset_and_keeps_nothing_else(run, tmp_path):
    with small_tmpfs(tmp_path / "mnt", "64m") as target:
        _export(run, target)
        assert sorted(os.listdir(target)) == ["data", "meta"]
        assert sorted(os.listdir(tmp_path)) == ["mnt", "run"]


def test_the_staging_folder_a_killed_export_left_in_a_mount_point_is_cleared_by_the_next(run, tmp_path):
    """Staged in the mount point, a killed export's folder is there, not beside it: the next export looks there."""
    with small_tmpfs(tmp_path / "mnt", "64m") as target:
        left = target / ".mnt.abcdefgh.partial"  # killed while writing: no process holds its lock, nothing moved
        (left / "data").mkdir(parents=True)
        (left / "data/file-000.parquet").write_bytes(b"half")
        _export(run, target)
        assert sorted(os.listdir(target)) == ["data", "meta"]
