"""``cellguard record``: info, export, recover, query; clear messages and exit codes on damaged files."""

from __future__ import annotations

import json

import pyarrow.parquet as pq
import pytest
from record_synth import record
from typer.testing import CliRunner

from cellguard.cli import app

runner = CliRunner()


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli")
    record(out, 4, 1000, events={1500: "position_clamp"}, failed={3})
    return out


def test_info_json(folder):
    result = runner.invoke(app, ["record", "info", str(folder), "--json"])
    assert result.exit_code == 0, result.output
    doc = json.loads(result.stdout)
    assert doc["health"]["ok"] and doc["context"]["site"] == "test-site"
    assert doc["cycles"]["acceptance"]["cycles"] == 2 and doc["cycles"]["production"]["succeeded"] == 1
    assert doc["events"] == {"position_clamp": 1}
    assert doc["span_s"][1] == pytest.approx(4.0, abs=0.01)


def test_export_csv_and_parquet(folder, tmp_path):
    result = runner.invoke(app, ["record", "export", str(folder), "--format", "csv", "-o", str(tmp_path / "t.csv"),
                                 "--rate", "decimated"])
    assert result.exit_code == 0, result.output
    lines = (tmp_path / "t.csv").read_text().splitlines()
    assert lines[0] == '"t_ns","cycle","joint","q_ref","q_cmd","q_meas","qd_meas","effort","current"'
    assert len(lines) == 1 + 4000 // 20 * 6
    result = runner.invoke(app, ["record", "export", str(folder), "--format", "parquet", "-o", str(tmp_path / "t.pq"),
                                 "--cycle", "1"])
    assert result.exit_code == 0, result.output
    table = pq.read_table(tmp_path / "t.pq")
    assert set(table["cycle"].to_pylist()) == {1} and table.num_rows == 1000 * 6  # full rate around the event


def test_export_rejects_an_unknown_format(folder, tmp_path):
    result = runner.invoke(app, ["record", "export", str(folder), "--format", "xlsx", "-o", str(tmp_path / "x")])
    assert result.exit_code == 2 and "--format" in result.output and "Traceback" not in result.output


def test_truncated_file_says_what_was_recovered_then_recover_finishes_it(folder, tmp_path):
    cut = tmp_path / "cut"
    cut.mkdir()
    data = (folder / "record.mcap").read_bytes()
    (cut / "record.mcap").write_bytes(data[: len(data) // 2])
    result = runner.invoke(app, ["record", "info", str(cut)])
    assert result.exit_code == 1
    assert "truncated: recovered" in result.output and "record recover" in result.output
    result = runner.invoke(app, ["record", "recover", str(cut), "-o", str(tmp_path / "fixed")])
    assert result.exit_code == 0, result.output
    result = runner.invoke(app, ["record", "info", str(tmp_path / "fixed"), "--json"])
    assert result.exit_code == 0 and json.loads(result.stdout)["health"]["finished"]
    # the copy is a whole file, not a whole run: it says what its source was (it read as complete)
    health = json.loads(result.stdout)["health"]
    assert health["recovered_from"].startswith("truncated: recovered")
    assert "; a recovered copy of a record that was truncated: recovered" in health["status"]
    again = tmp_path / "again"
    assert runner.invoke(app, ["record", "recover", str(tmp_path / "fixed"), "-o", str(again)]).exit_code == 0
    copy = json.loads(runner.invoke(app, ["record", "info", str(again), "--json"]).stdout)["health"]
    assert copy["recovered_from"].startswith("complete: ") and "a recovered copy of a record that was" in copy["status"]


def test_garbage_is_one_line_and_exit_2(tmp_path):
    (tmp_path / "record.mcap").write_bytes(b"\x00" * 1000)
    result = runner.invoke(app, ["record", "info", str(tmp_path)])
    assert result.exit_code == 2
    assert result.output.startswith("error: ") and "nothing can be recovered" in result.output


def test_query_the_index(folder):
    result = runner.invoke(app, ["record", "query", str(folder),
                                 'SELECT cycle, "current_peak.elbow" AS peak FROM cycles WHERE NOT success'])
    assert result.exit_code == 0, result.output
    assert [json.loads(line) for line in result.stdout.splitlines()] == [{"cycle": 3, "peak": 3.0}]
    result = runner.invoke(app, ["record", "query", str(folder), "SELECT nope FROM cycles"])
    assert result.exit_code == 2 and result.output.startswith("error: sql:")


def test_a_query_too_big_for_memory_fails_and_writes_nothing(folder, tmp_path, monkeypatch):
    from cellguard.record import query

    monkeypatch.setattr(query, "MEMORY_LIMIT", "50MB")  # by default DuckDB spills this sort into ./.tmp
    monkeypatch.chdir(tmp_path)
    result = runner.invoke(app, ["record", "query", str(folder),
                                 "SELECT range AS n, md5(range::VARCHAR) AS h FROM range(1000000) ORDER BY h"])
    assert list(tmp_path.iterdir()) == []
    assert result.exit_code == 2 and result.output.startswith("error: sql: the query needs more than 50MB")
    assert result.output.count("\n") == 1
