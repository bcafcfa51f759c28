"""`cellguard diagnose RUN --acceptance OTHER`: a baseline taken from a record that is not whole is said,
in one line, with exit 1, as for the diagnosed record itself (real records from `cellguard run`)."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from cellguard.cli import app
from cli_util import record_run

runner = CliRunner()


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    return record_run(tmp_path_factory.mktemp("acc"))


def test_a_truncated_acceptance_record_is_warned_of_and_exits_1(recorded, tmp_path):
    cut = tmp_path / "cut"
    cut.mkdir()
    data = (recorded / "record.mcap").read_bytes()
    (cut / "record.mcap").write_bytes(data[: len(data) * 3 // 4])  # its acceptance cycles are still there
    for command, extra in (("diagnose", ["--json"]), ("report", ["-o", str(tmp_path / "r.html")])):
        result = runner.invoke(app, [command, str(recorded), "--acceptance", str(cut), "--no-fleet", *extra])
        assert result.exit_code == 1, result.output
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"warning: {cut}: truncated"), result.stderr
    out = json.loads(runner.invoke(app, ["diagnose", str(recorded), "--acceptance", str(cut), "--no-fleet",
                                         "--json"]).stdout)
    assert out["acceptance_record"]["ok"] is False and out["record"]["ok"] is True
    assert out["findings"][0]["cause"] == "fixture_shift"


def test_a_whole_acceptance_record_exits_0(recorded):
    result = runner.invoke(app, ["diagnose", str(recorded), "--acceptance", str(recorded), "--no-fleet", "--json"])
    assert result.exit_code == 0 and not result.stderr, result.output
    assert json.loads(result.stdout)["acceptance_record"]["ok"] is True
