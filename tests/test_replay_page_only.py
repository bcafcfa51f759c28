"""``replay -o`` replaces only a page cellguard wrote (or an empty file): a record made with a calibrated profile is
replayed in that profile, found by its sha256, so its file, its calibrated MJCF and the kept old profile are all read
without being named, and ``-o`` naming one of them wrote the page over it (exit 0; the next run failed on it)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest
from cli_util import one_error
from typer.testing import CliRunner

from cellguard.calibrate.excitation import excitation_scenario, excite
from cellguard.cli import app
from cellguard.robot.arm_cell import ASSETS
from cellguard.robot.registry import make_cell
from cellguard.runtime.loop import run_scenario
from cellguard.scenario import Scenario

ARM = "arm-pick-place"
STOCK = make_cell(ARM).profile.version  # the kept copy's version: the profile before its calibration
runner = CliRunner()


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """``cal/arm_profile.yaml`` calibrated by ``identify --write`` (its MJCF and the kept stock copy beside it), and
    ``run/``: one cycle recorded with ``calibration:`` that profile."""
    base = tmp_path_factory.mktemp("page_only")
    (base / "cal").mkdir()
    excite(excitation_scenario(ARM, 3.0), base / "ex")
    profile = base / "cal" / "arm_profile.yaml"
    profile.write_bytes((ASSETS / "arm_profile.yaml").read_bytes())
    written = runner.invoke(app, ["identify", str(base / "ex"), "--params", "friction", "--write", str(profile)])
    assert written.exit_code == 0, written.output
    run_scenario(Scenario(cell=ARM, acceptance_cycles=1, production_cycles=0, calibration=profile), base / "run")
    return base


def digests(folder: Path) -> dict[str, str]:
    return {f.name: hashlib.sha256(f.read_bytes()).hexdigest() for f in sorted(folder.iterdir())}


@pytest.mark.parametrize("name", ["arm_profile.yaml", "arm_profile.*.xml", f"arm_profile.{STOCK}.yaml"])
def test_the_page_never_replaces_the_profile_the_replay_reads_its_mjcf_or_its_kept_copy(site, name):
    target = next((site / "cal").glob(name))
    before = digests(site / "cal")
    line = one_error(runner.invoke(app, ["replay", str(site / "run"), "--cycle", "0", "-o", str(target)]))
    assert line == (f"error: -o {target}: exists and is not an HTML page cellguard wrote; cellguard replaces only its "
                    "own (or an empty file): choose another path, or remove the file first"), line
    assert digests(site / "cal") == before


def test_any_other_file_is_kept_as_well(site, tmp_path):
    notes = tmp_path / "notes.html"
    notes.write_text("<!doctype html><p>the technician's notes</p>\n")
    line = one_error(runner.invoke(app, ["replay", str(site / "run"), "--cycle", "0", "-o", str(notes)]))
    assert "is not an HTML page cellguard wrote" in line
    assert notes.read_text() == "<!doctype html><p>the technician's notes</p>\n"


def test_an_earlier_replay_page_and_an_empty_file_are_replaced(site, tmp_path):
    """The page replay renders begins as ``PAGE_HEAD`` says: a second replay to the same page is not refused."""
    page, empty = tmp_path / "page.html", tmp_path / "empty.html"
    empty.touch()  # as ``mktemp`` leaves it
    for out in (page, page, empty):
        result = runner.invoke(app, ["replay", str(site / "run"), "--cycle", "0", "-o", str(out)])
        assert result.exit_code == 0, result.output
        assert "<svg" in out.read_text()
