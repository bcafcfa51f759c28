"""``cellguard replay``: its page never lands on the record, its run folder's files or its own inputs; the
output is checked before anything is simulated; a stand-mounted record replays on the stand; a damaged
record replays with one warning and exit 1."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import pytest
from cli_util import one_error
from typer.testing import CliRunner

from cellguard.calibrate.excitation import excitation_scenario, excite
from cellguard.calibrate.replay import replay
from cellguard.calibrate.stand import Stand
from cellguard.cli import app
from cellguard.record.scan import scan
from cellguard.robot.arm_cell import ASSETS

runner = CliRunner()


@pytest.fixture(scope="module")
def excited(tmp_path_factory):
    """A 3 s arm excitation: one cycle of ticks and chunks."""
    out = tmp_path_factory.mktemp("replay") / "ex"
    excite(excitation_scenario("arm-pick-place", 3.0), out)
    return out


@pytest.fixture
def ex(excited, tmp_path):
    """A copy per test: a command that wrongly writes into it spoils no other test."""
    return Path(shutil.copytree(excited, tmp_path / "ex"))


def digests(*paths: Path) -> dict[str, str]:
    files = [f for p in paths for f in (sorted(p.rglob("*")) if p.is_dir() else [p]) if f.is_file()]
    return {str(f): hashlib.sha256(f.read_bytes()).hexdigest() for f in files}


def damage_one_chunk(file: Path) -> None:
    """Flip 64 bytes inside the middle chunk: its CRC fails, the rest reads."""
    chunks = scan(file).chunks
    c = chunks[len(chunks) // 2]
    data = bytearray(file.read_bytes())
    at = c.offset + c.length // 2
    data[at:at + 64] = bytes(b ^ 0xFF for b in data[at:at + 64])
    file.write_bytes(bytes(data))


@pytest.mark.parametrize("target, says", [
    ("ex/record.mcap", "is the record being read"),
    ("ex/summary.json", "is in the run folder"),
    ("ex/index/page.html", "is in the run folder"),
    ("profile.yaml", "is the --profile file being read"),
    ("ex", "is a run folder"),
])
def test_the_page_never_replaces_the_record_its_files_or_the_profile(ex, tmp_path, target, says):
    profile = tmp_path / "profile.yaml"
    profile.write_bytes((ASSETS / "arm_profile.yaml").read_bytes())
    before = digests(ex, profile)
    line = one_error(runner.invoke(app, ["replay", str(ex), "--cycle", "0", "--profile", str(profile),
                                         "-o", str(tmp_path / target)]))
    assert line.startswith(f"error: -o {tmp_path / target}: ") and says in line, line
    assert digests(ex, profile) == before


def test_the_page_is_checked_before_the_record_is_read(ex, tmp_path):
    """--cycle 99 does not exist: the error names -o (a page that could not be written used to fail only after
    the whole simulation)."""
    (tmp_path / "afile").write_text("mine\n")
    line = one_error(runner.invoke(app, ["replay", str(ex), "--cycle", "99", "-o", str(tmp_path / "afile/p.html")]))
    assert line.startswith(f"error: -o {tmp_path / 'afile/p.html'}: {tmp_path / 'afile'} is a file, not a folder")


def test_the_mcap_file_replays_into_its_folder_and_paths_print_as_given(ex, tmp_path):
    """Given the .mcap file, the default page goes beside it (it used to fail, after the whole simulation, on
    RECORD/record.mcap/ as a folder); the path, escape code and all, is printed escaped."""
    odd = Path(shutil.move(ex, tmp_path / "ex\x1b[31mRED"))
    before = digests(odd)
    result = runner.invoke(app, ["replay", str(odd / "record.mcap"), "--cycle", "0"])
    assert result.exit_code == 0, result.output
    page = odd / "replay-cycle-0.html"
    assert "<svg" in page.read_text()
    shown = str(page).replace("\x1b", "\\x1b")  # the escape code written out, never sent to the terminal
    assert "\x1b" not in result.output and f"  {shown}\n" in result.stdout
    assert {k: v for k, v in digests(odd).items() if not k.endswith(".html")} == before


def test_a_profile_with_the_nominal_model_is_refused(ex, tmp_path):
    line = one_error(runner.invoke(app, ["replay", str(ex), "--cycle", "0", "--model", "nominal",
                                         "--profile", str(tmp_path / "none.yaml")]))
    assert "--profile: only with --model calibrated" in line
    assert not list(ex.glob("replay-*.html"))


def test_a_damaged_record_replays_with_one_warning_and_exit_1(ex, tmp_path):
    damage_one_chunk(ex / "record.mcap")
    result = runner.invoke(app, ["replay", str(ex), "--cycle", "0", "-o", str(tmp_path / "page.html")])
    assert result.exit_code == 1, result.output
    warnings = result.stderr.splitlines()
    assert len(warnings) == 1 and warnings[0].startswith(f"warning: {ex}: damaged"), result.stderr
    assert (tmp_path / "page.html").is_file()


def test_a_record_made_on_a_stand_replays_on_the_stand(tmp_path):
    """The quadruped excited on a stand: replayed without it, the body falls and the currents are nothing like
    the record's (mean NRMSE 25); on the stand the simulation retraces it."""
    out = tmp_path / "stand"
    excite(excitation_scenario("quadruped-turns", 3.0), out, stand=Stand())
    r = replay(out, 0, model="nominal")
    assert r.mismatch["cost"] < 1.0, r.mismatch
