"""``cellguard identify``: each record counts once, a record that is not whole is warned about (exit 1) and
never stored as a calibration, and ``--write`` takes nothing from a profile it has not checked, stores no
negative joint term, writes no file in a run folder and follows a link to its target."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import pytest
import yaml
from arm_excitation import ARM, excited, profile  # noqa: F401 (fixtures)
from cli_util import one_error
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.embodiment import load_profile
from cellguard.record.scan import scan
from cellguard.robot.arm_cell import ASSETS
from cellguard.robot.registry import make_cell

runner = CliRunner()


def edited(profile: Path, edit) -> Path:
    raw = yaml.safe_load(profile.read_text())
    edit(raw)
    profile.write_text(yaml.safe_dump(raw, sort_keys=False))
    return profile


def listing(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir()) if p.is_file()}


def test_a_record_given_twice_is_refused_naming_both(excited):
    """Counted twice, a record's ticks shrank every interval (and --write stored them)."""
    for again in (excited, excited / "record.mcap", Path(f"{excited}/../{excited.name}/")):
        line = one_error(runner.invoke(app, ["identify", str(excited), str(again), "--params", "friction"]))
        assert f"{again} (record argument 2) is the same record as {excited} (argument 1)" in line, line


def test_params_with_only_is_refused(excited):
    line = one_error(runner.invoke(app, ["identify", str(excited), "--params", "friction", "--only", "elbow,friction"]))
    assert "--params: not with --only" in line


def test_a_damaged_record_warns_exits_1_and_is_never_written(excited, profile, tmp_path):
    damaged = Path(shutil.copytree(excited, tmp_path / "damaged"))
    chunks = scan(damaged / "record.mcap").chunks
    c = chunks[len(chunks) // 2]
    data = bytearray((damaged / "record.mcap").read_bytes())
    at = c.offset + c.length // 2
    data[at:at + 64] = bytes(b ^ 0xFF for b in data[at:at + 64])
    (damaged / "record.mcap").write_bytes(bytes(data))

    result = runner.invoke(app, ["identify", str(damaged), "--params", "friction"])
    assert result.exit_code == 1, result.output
    warnings = [line for line in result.stderr.splitlines() if line.startswith("warning:")]
    assert len(warnings) == 1 and warnings[0].startswith(f"warning: {damaged}: damaged"), result.stderr

    before = listing(profile.parent)
    line = one_error(runner.invoke(app, ["identify", str(damaged), "--params", "friction", "--write", str(profile)]))
    assert f"--write: {damaged} is not whole (damaged" in line
    assert listing(profile.parent) == before


@pytest.mark.parametrize("edit, says", [
    (lambda r: r["measured"].insert(0, 42), "measured[0]: expected a mapping"),
    (lambda r: r.__setitem__("version", "x/../../escaped"), "version: 'x/../../escaped' cannot name a file"),
    (lambda r: r.__setitem__("version", "a\0b"), r"version: 'a\x00b' holds control characters"),
])
def test_write_checks_the_whole_profile_before_using_it(excited, profile, edit, says):
    """A malformed ``measured`` entry was an AttributeError traceback, a version with / or NUL a ValueError
    one (it names the kept copy's file)."""
    edited(profile, edit)
    before = listing(profile.parent)
    line = one_error(runner.invoke(app, ["identify", str(excited), "--params", "friction", "--write", str(profile)]))
    assert line.startswith(f"error: {profile}: {says}"), line
    assert listing(profile.parent) == before and not (profile.parent / "escaped.yaml").exists()


def test_a_negative_friction_is_reported_not_written(excited, profile):
    """With the elbow's damping held far too high, its re-fitted friction absorbs the difference and comes out
    near -2.3 N*m; identify used to write that into the profile and the calibrated MJCF."""
    edited(profile, lambda r: r["measured"].append({"joint": "elbow", "parameter": "damping",
                                                    "value": "20 N*m*s/rad", "measured": "2026-10-14",
                                                    "method": "typed in"}))
    before = listing(profile.parent)
    result = runner.invoke(app, ["identify", str(excited), "--only", "elbow,friction", "--write", str(profile)])
    assert result.exit_code == 1, result.output
    warnings = result.stderr.splitlines()
    assert len(warnings) == 2 and warnings[0].startswith("warning: elbow friction -"), result.stderr
    assert "below zero" in warnings[0] and f"--write: {profile} not written" in warnings[1]
    assert "friction elbow" in result.stdout and "calibration version" not in result.stdout
    assert listing(profile.parent) == before


def test_write_into_a_run_folder_or_over_a_record_is_refused(excited, tmp_path):
    run = Path(shutil.copytree(excited, tmp_path / "ex"))
    inside = run / "arm_profile.yaml"
    inside.write_bytes((ASSETS / "arm_profile.yaml").read_bytes())
    before = listing(run)
    for target, says in ((inside, "is in the run folder"), (run / "record.mcap", "is the record being read")):
        line = one_error(runner.invoke(app, ["identify", str(run), "--params", "friction", "--write", str(target)]))
        assert line.startswith(f"error: --write {target}: {says}"), line
    assert listing(run) == before


def test_write_through_a_link_rewrites_its_target_and_prints_paths_as_given(excited, profile, tmp_path):
    links = tmp_path / "links\x1b[2J"
    links.mkdir()
    link = links / "arm.yaml"
    link.symlink_to(profile)
    result = runner.invoke(app, ["identify", str(excited), "--params", "friction", "--write", str(link)])
    assert result.exit_code == 0, result.output
    assert link.is_symlink() and link.resolve() == profile and sorted(p.name for p in links.iterdir()) == ["arm.yaml"]
    written = load_profile(make_cell(ARM).model, profile)
    assert written.calibration is not None and (profile.parent / written.calibration.mjcf).is_file()
    assert (profile.parent / "arm_profile.2026-11-01.yaml").is_file()  # the kept copy, beside the target
    assert "\x1b" not in result.output and f"{link}".replace("\x1b", "\\x1b") in result.stdout
