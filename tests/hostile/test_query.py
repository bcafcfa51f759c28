"""Class 1: ``record query`` is read-only and confined to the record's own tables.

Every hostile statement is one error line and exit 2, and the record, its index and the files
around it are byte-identical afterwards; the queries a user writes still answer.
"""

from __future__ import annotations

import json

import pytest
from record_synth import record

from .expect import refused, runner, snapshot
from cellguard.cli import app


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("query")
    folder = root / "run"
    record(folder, 4, 1000, events={1500: "position_clamp"}, failed={3})
    (root / "secret.txt").write_text("do not read me\n")
    return folder


def _hostile(folder):
    outside = folder.parent
    return [
        f"SELECT content FROM read_text('{outside}/secret.txt')",
        "SELECT * FROM read_csv('/etc/passwd', sep = ':')",
        f"SELECT * FROM glob('{folder}/**')",
        f"SELECT * FROM read_parquet('{folder}/index/cycles/*/*.parquet')",
        "SELECT * FROM read_parquet('https://example.com/x.parquet')",
        f"COPY (SELECT 1) TO '{folder}/record.mcap'",
        f"COPY (SELECT * FROM cycles) TO '{folder}/index/cycles/evil.parquet'",
        f"COPY cycles FROM '{outside}/secret.txt'",
        f"EXPORT DATABASE '{outside}/dump'",
        f"ATTACH '{outside}/other.duckdb' AS other",
        "ATTACH ':memory:' AS other",
        "INSTALL httpfs",
        "LOAD httpfs",
        "SET enable_external_access = true",
        "RESET lock_configuration",
        "PRAGMA enable_profiling",
        "CREATE TABLE x AS SELECT 1",
        "INSERT INTO cycles (cycle) VALUES (99)",
        "DELETE FROM events",
        "DROP TABLE cycles",
        "SELECT 1; COPY (SELECT 1) TO 'x.csv'",
        "SELECT * FROM query('CREATE TABLE y AS SELECT 1')",
        "CALL pragma_version()",
        "",
        "   ",
        "-- only a comment",
        "/* only a comment */ ;",
    ]


def test_every_write_read_attach_install_is_refused(run_dir):
    before, around = snapshot(run_dir), snapshot(run_dir.parent)
    for sql in _hostile(run_dir):
        refused(["record", "query", run_dir, "--", sql], contains="sql")
    assert snapshot(run_dir) == before
    assert snapshot(run_dir.parent) == around  # nothing written beside it either (dump, other.duckdb)


@pytest.mark.parametrize("sql,check", [
    ('SELECT cycle, "current_peak.elbow" AS peak FROM cycles WHERE NOT success',
     lambda rows: rows == [{"cycle": 3, "peak": 3.0}]),
    ("SELECT phase, count(*) AS n FROM cycles GROUP BY phase ORDER BY phase",
     lambda rows: rows == [{"phase": "acceptance", "n": 2}, {"phase": "production", "n": 2}]),
    ("SELECT phase, count(*) AS cycles, avg(success::INT) AS success FROM cycles GROUP BY phase ORDER BY phase",
     lambda rows: rows == [{"phase": "acceptance", "cycles": 2, "success": 1.0},
                           {"phase": "production", "cycles": 2, "success": 0.5}]),  # docs/hardening.md item 9
    ("SELECT t_ns, kind, reason FROM events WHERE category IS NOT NULL", lambda rows: rows == []),  # item 9
    ("SELECT kind, cycle FROM events", lambda rows: rows == [{"kind": "position_clamp", "cycle": 1}]),
    ("SELECT c.cycle, e.kind FROM cycles c JOIN events e USING (cycle)",
     lambda rows: rows == [{"cycle": 1, "kind": "position_clamp"}]),
    ("WITH a AS (SELECT quantile_cont(t_end_ns - t_start_ns, 0.5) AS q FROM cycles) SELECT q > 0 AS ok FROM a",
     lambda rows: rows == [{"ok": True}]),
    ("DESCRIBE cycles", lambda rows: "cycle" in {r["column_name"] for r in rows}),
    ("SUMMARIZE events", lambda rows: len(rows) > 3),
    ("EXPLAIN SELECT * FROM cycles", lambda rows: len(rows) >= 1),
    ("SELECT count(*) AS n FROM cycles -- a trailing comment", lambda rows: rows == [{"n": 4}]),
])
def test_queries_still_answer(run_dir, sql, check):
    result = runner.invoke(app, ["record", "query", str(run_dir), sql])
    assert result.exit_code == 0, result.output
    assert check([json.loads(line) for line in result.stdout.splitlines()])


def test_a_runaway_query_stops_at_its_time_limit(run_dir):
    line = refused(["record", "query", run_dir, "SELECT count(*) FROM range(1000000000000)", "--timeout", "0.5"])
    assert "0.5 s" in line


def test_a_damaged_index_part_is_one_line(tmp_path):
    folder = tmp_path / "run"
    record(folder, 2, 500)
    part = next((folder / "index" / "cycles").rglob("*.parquet"))
    part.write_bytes(part.read_bytes()[:40] + b"\0" * 64)
    before = snapshot(folder)
    refused(["record", "query", folder, "SELECT * FROM cycles"], contains="record recover")
    assert snapshot(folder) == before
