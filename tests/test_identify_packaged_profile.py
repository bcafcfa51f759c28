"""``identify --write`` refuses a cell's own profile, installed with cellguard: written, every run of the cell on
that install (no ``calibration:`` named) ran the calibration, exit 0. A copy of it is what a site calibrates."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import pytest
from cli_util import one_error
from typer.testing import CliRunner

from cellguard.calibrate.write import check_write_target, write_profile
from cellguard.cli import app
from cellguard.errors import ProfileError
from cellguard.robot.arm_cell import ASSETS
from cellguard.robot.registry import make_cell

ARM = "arm-pick-place"
STOCK = ASSETS / "arm_profile.yaml"
runner = CliRunner()


def test_the_installed_profile_is_refused_before_any_record_is_read(tmp_path):
    """``--cell`` and a record that does not exist: the target is refused first, and nothing in the package changes
    (the command fails either way, so nothing is written even where the refusal is missing)."""
    before = {f.name: hashlib.sha256(f.read_bytes()).hexdigest() for f in ASSETS.iterdir() if f.is_file()}
    line = one_error(runner.invoke(app, ["identify", str(tmp_path / "no-record"), "--cell", ARM,
                                         "--write", str(STOCK)]))
    assert line.startswith(f"error: --write: {STOCK} is in the installed package cellguard ("), line
    assert "copy it to another folder and write the copy" in line
    assert {f.name: hashlib.sha256(f.read_bytes()).hexdigest() for f in ASSETS.iterdir() if f.is_file()} == before


@pytest.mark.parametrize("how", ["link", "folder link"])
def test_a_link_to_it_is_refused_too(tmp_path, how):
    if how == "link":
        os.symlink(STOCK, tmp_path / "arm_profile.yaml")
        named = tmp_path / "arm_profile.yaml"
    else:
        os.symlink(ASSETS, tmp_path / "assets")
        named = tmp_path / "assets" / "arm_profile.yaml"
    with pytest.raises(ProfileError, match=rf"^--write: {named} \(a link to {STOCK.resolve()}\) is in the installed "
                                           "package cellguard"):
        check_write_target(named, make_cell(ARM))


def test_a_script_writing_it_is_refused_as_the_command_is():
    """write_profile is what the command calls once it has checked; a script calling it checked nothing."""
    before = STOCK.read_bytes()
    with pytest.raises(ProfileError, match="is in the installed package cellguard"):
        write_profile(STOCK, make_cell(ARM), {"parameters": []}, "2026-11-27")
    assert STOCK.read_bytes() == before


def test_a_copy_of_it_is_taken(tmp_path):
    copy = Path(tmp_path / "arm_profile.yaml")
    copy.write_bytes(STOCK.read_bytes())
    check_write_target(copy, make_cell(ARM))  # no error
