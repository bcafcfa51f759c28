"""``excite --seconds`` is at least the fade-in and half the base period (7 s): a 1 s excitation, still fading in,
gave shoulder_lift damping 0.382 [0.330, 0.435] against a truth of 0.5 and ``identify --write`` stored it."""

from __future__ import annotations

from cli_util import one_error
from typer.testing import CliRunner

from cellguard.calibrate.excitation import BASE_HZ, FADE_S
from cellguard.cli import app

runner = CliRunner()


def test_a_shorter_excitation_is_refused_before_anything_is_recorded(tmp_path):
    assert FADE_S + 0.5 / BASE_HZ == 7.0
    out = tmp_path / "ex"
    line = one_error(runner.invoke(app, ["excite", "arm-pick-place", "--seconds", "6.9", "--out", str(out)]))
    assert line == ("error: --seconds: 6.9 is outside 7..3600 s (the fade-in, then half the slowest harmonic's "
                    "period: a shorter record fits friction and damping wrong)"), line
    assert not out.exists()


def test_the_shortest_is_recorded(tmp_path):
    result = runner.invoke(app, ["excite", "arm-pick-place", "--seconds", "7", "--out", str(tmp_path / "ex")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "ex" / "record.mcap").is_file()
