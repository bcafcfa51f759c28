"""identify --write adds files named after the profile beside it (NAME.VERSION.yaml, NAME.DATE-cal-HASH.xml): a
name over 255 bytes is refused in one line before any record is read, never a traceback after the fit."""

from __future__ import annotations

import re

import yaml
from arm_excitation import ARM, excited, profile  # noqa: F401 (fixtures)
from cli_util import one_error
from typer.testing import CliRunner

from cellguard.cli import app

runner = CliRunner()


def _versioned(path, version: str) -> None:
    path.write_text(re.sub(r"(?m)^version:.*$", f"version: '{version}'", path.read_text()))


def test_a_version_too_long_for_the_kept_copy_is_refused_in_one_line(excited, profile):
    _versioned(profile, "v" * 300)
    before = profile.read_bytes()
    line = one_error(runner.invoke(app, ["identify", str(excited), "--write", str(profile)]))
    assert "old profile's copy" in line and "300 bytes" in line and "shorter version" in line, line
    assert sorted(p.name for p in profile.parent.iterdir()) == [profile.name]
    assert profile.read_bytes() == before


def test_the_name_is_checked_before_any_record_is_read(profile, tmp_path):
    _versioned(profile, "v" * 300)
    line = one_error(runner.invoke(app, ["identify", str(tmp_path / "no-record"), "--cell", ARM,
                                         "--write", str(profile), "--only", "elbow,friction"]))
    assert "300 bytes" in line and "no record" not in line, line


def test_a_profile_name_too_long_for_the_calibrated_mjcf_is_refused(profile, tmp_path):
    long = profile.rename(tmp_path / f"{'p' * 235}.yaml")  # NAME.VERSION.yaml fits; NAME.DATE-cal-HASH.xml does not
    line = one_error(runner.invoke(app, ["identify", str(tmp_path / "no-record"), "--cell", ARM,
                                         "--write", str(long)]))
    assert "calibrated MJCF" in line and "shorter file name" in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == [long.name]


def test_a_long_version_that_fits_is_written_and_kept(excited, profile):
    _versioned(profile, "v" * 200)  # arm_profile.vvv...vvv.yaml: 217 bytes
    result = runner.invoke(app, ["identify", str(excited), "--params", "friction", "--write", str(profile)])
    assert result.exit_code == 0, result.output
    assert (profile.parent / f"arm_profile.{'v' * 200}.yaml").is_file()


def test_a_kept_copy_is_not_rewritten(excited, profile):
    """Rewritten in place, a kept copy's release could no longer run (its bytes went to NAME.V.V.yaml, a name no one
    looks for): refused before the fit, nothing written; the profile it was kept from is written as before."""
    first = runner.invoke(app, ["identify", str(excited), "--params", "friction", "--write", str(profile)])
    assert first.exit_code == 0, first.output
    (kept,) = [p for p in profile.parent.glob("arm_profile.*.yaml")]
    names, before = sorted(p.name for p in profile.parent.iterdir()), kept.read_bytes()
    line = one_error(runner.invoke(app, ["identify", str(excited), "--params", "friction", "--write", str(kept)]))
    assert f"{kept} is the copy of version" in line and "kept when its profile was recalibrated" in line, line
    assert sorted(p.name for p in profile.parent.iterdir()) == names and kept.read_bytes() == before


def test_a_profile_named_like_a_kept_copy_but_kept_from_nothing_is_written(excited, profile):
    """Only a copy beside the NAME.yaml it was kept from is one: a user's own myarm.VERSION.yaml was refused."""
    version = yaml.safe_load(profile.read_text())["version"]
    own = profile.rename(profile.with_name(f"myarm.{version}.yaml"))
    result = runner.invoke(app, ["identify", str(excited), "--params", "friction", "--write", str(own)])
    assert result.exit_code == 0, result.output
