"""identify --write never gives one calibration version id to two different calibrations. The id hashed the measured
values, the MJCF and the version replaced, not the rest of the profile: a profile hand-edited (a limit) that kept its
version string was written under the very id of the calibration written from it before, and the edit went unkept
(the old copy is never overwritten). A write whose id's MJCF or kept copy already exists with other contents is
refused naming it."""

from __future__ import annotations

from pathlib import Path

import yaml
from arm_excitation import excited, profile  # noqa: F401 (fixtures)
from cli_util import one_error
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.robot.arm_cell import ASSETS

runner = CliRunner()


def write(record: Path, path: Path) -> str:
    """``identify --write`` of the profile at ``path`` (asserted to exit 0): the new calibration version."""
    result = runner.invoke(app, ["identify", str(record), "--params", "friction,damping,armature", "--write",
                                 str(path)])
    assert result.exit_code == 0, result.output
    return yaml.safe_load(path.read_text())["version"]


def slower(path: Path) -> None:
    """Edit the profile at ``path`` by hand, keeping its version: elbow's velocity limit lowered."""
    raw = yaml.safe_load(path.read_text())
    raw["joints"]["elbow"]["velocity"] = "2.5 rad/s"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))


def files(folder: Path) -> list[tuple[str, bytes]]:
    return sorted((p.name, p.read_bytes()) for p in folder.iterdir() if p.is_file())


def profile_copy(folder: Path) -> Path:
    """The arm's profile copied into ``folder``."""
    folder.mkdir()
    (folder / "arm_profile.yaml").write_bytes((ASSETS / "arm_profile.yaml").read_bytes())
    return folder / "arm_profile.yaml"


def test_profiles_that_differ_get_different_ids(excited, tmp_path):
    first = write(excited, profile_copy(tmp_path / "a"))
    slower(other := profile_copy(tmp_path / "b"))  # the same version string, another limit
    assert write(excited, other) != first


def test_an_edited_profile_that_kept_its_version_is_refused_naming_the_kept_copy(excited, profile):
    v1 = write(excited, profile)
    write(excited, profile)
    kept = profile.with_name(f"arm_profile.{v1}.yaml")
    profile.write_bytes(kept.read_bytes())  # back to v1 (a rollback: written again as it was)
    slower(profile)  # ... then edited, still called v1
    before = files(profile.parent)
    line = one_error(runner.invoke(app, ["identify", str(excited), "--params", "friction,damping,armature",
                                         "--write", str(profile)]))
    assert line == (f"error: --write: {profile} is version {v1}, but the copy of version {v1} kept beside it "
                    f"({kept.name}) differs: the profile was edited and kept its version; give it a version of its "
                    "own (nothing written)"), line
    assert files(profile.parent) == before
    profile.write_bytes(kept.read_bytes())  # the rollback itself is written
    write(excited, profile)


def test_an_existing_mjcf_of_the_new_version_with_other_contents_is_refused(excited, profile):
    v1 = write(excited, profile)
    v2 = write(excited, profile)
    mjcf = profile.with_name(f"arm_profile.{v2}.xml")
    mjcf.write_text(mjcf.read_text().replace("<mujoco", "<!-- edited -->\n<mujoco", 1))
    profile.write_bytes(profile.with_name(f"arm_profile.{v1}.yaml").read_bytes())  # the same write again: id v2
    before = files(profile.parent)
    line = one_error(runner.invoke(app, ["identify", str(excited), "--params", "friction,damping,armature",
                                         "--write", str(profile)]))
    assert line == (f"error: --write: the calibrated MJCF {mjcf} of version {v2} exists with other contents; that "
                    "version names another calibration: move it away or restore it (nothing written)"), line
    assert files(profile.parent) == before
