"""``cellguard excite``'s output: the help keeps its units and the record's path prints as given."""

from __future__ import annotations

from typer.testing import CliRunner

from cellguard.cli import app

runner = CliRunner()


def test_help_keeps_the_unit():
    result = runner.invoke(app, ["excite", "--help"], env={"COLUMNS": "200"})
    assert "Length of the excitation [s]." in result.output


def test_the_record_path_prints_as_given(tmp_path):
    out = tmp_path / "ex\x1b[31mRED"
    result = runner.invoke(app, ["excite", "arm-pick-place", "--seconds", "7", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "\x1b" not in result.output
    assert result.stdout.startswith(str(out).replace("\x1b", "\\x1b") + ": 7 s of excitation recorded")
