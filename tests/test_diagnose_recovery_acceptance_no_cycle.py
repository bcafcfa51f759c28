"""``diagnose --acceptance OTHER`` on a record with no finished cycle (its run killed in its first) says so, before the
baseline's features are looked for in it: it said "baseline is of another cell: 70 of 70 of the baseline's features
are not in this record" of two records of one cell and profile."""

from __future__ import annotations

from record_synth import record
from typer.testing import CliRunner

from cellguard.cli import app


def test_a_record_with_no_finished_cycle_is_named_so_against_another_acceptance(tmp_path):
    record(tmp_path / "accepted", 10, 3)  # 5 acceptance cycles, the same robot and profile
    record(tmp_path / "run", 0, 3)
    kept = sorted(p.name for p in (tmp_path / "run").iterdir())  # the record and its (empty) index
    for command in (["diagnose"], ["report", "-o", str(tmp_path / "page.html")]):
        result = CliRunner().invoke(app, [*command, str(tmp_path / "run"), "--acceptance", str(tmp_path / "accepted")])
        assert result.exit_code == 2, result.output
        assert result.output.strip() == f"error: {tmp_path / 'run'}: the record has no finished cycle to diagnose"
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == kept  # nothing written beside them
    assert not (tmp_path / "page.html").exists()


def test_an_acceptance_record_with_too_few_cycles_is_named(tmp_path):
    """It said only "baseline: needs at least 5 acceptance cycles, got 0", not of which record."""
    record(tmp_path / "run", 10, 3)
    record(tmp_path / "empty", 0, 3)
    result = CliRunner().invoke(app, ["diagnose", str(tmp_path / "run"), "--acceptance", str(tmp_path / "empty")])
    assert result.exit_code == 2, result.output
    assert " ".join(result.output.split()) == (f"error: --acceptance {tmp_path / 'empty'}: baseline: needs at least "
                                               f"5 acceptance cycles, got 0")
