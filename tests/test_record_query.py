"""``record query``: memory and time limits on the query's own process, indexes read by their literal path,
empty tables with their columns, EXPLAIN only of a SELECT, faithful JSON, the .mcap file as the run folder."""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import sys
import time

import duckdb
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from record_synth import record
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import RecordError
from cellguard.record import query
from cellguard.record import index
from cellguard.record.index import IndexWriter, connect, event_row

runner = CliRunner()


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("query") / "run"
    record(folder, 4, 200, events={300: "position_clamp"}, failed={3})
    return folder


@pytest.fixture(scope="module")
def quiet_dir(tmp_path_factory):
    """A record without a single event: its events table has no part."""
    folder = tmp_path_factory.mktemp("quiet") / "run"
    record(folder, 2, 200)
    return folder


def _rows(*args) -> list[dict]:
    result = runner.invoke(app, ["record", "query", *map(str, args)])
    assert result.exit_code == 0, (result.output, result.exception)
    return [json.loads(line, parse_constant=_no_constant) for line in result.stdout.splitlines()]


def _refused(*args, contains: str) -> str:
    """Exit 2 with exactly one ``error:`` line on stderr holding ``contains`` and no traceback."""
    result = runner.invoke(app, ["record", "query", *map(str, args)])
    assert result.exit_code == 2, (result.exit_code, result.output, result.exception)
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in result.output, result.stderr
    assert contains in lines[0], lines[0]
    return lines[0]


def _no_constant(name):
    raise AssertionError(f"{name} is not JSON")


# 1. memory and time


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the OS memory limit is Linux's RLIMIT_DATA")
def test_a_scalar_function_cannot_take_more_memory_than_the_cap(run_dir, monkeypatch):
    """DuckDB's memory_limit does not count what ``repeat`` allocates: 300 MB passed a 200 MB limit."""
    monkeypatch.setattr(query, "MEMORY_LIMIT", "200MB")
    _refused(run_dir, "SELECT length(repeat('x', 300000000)) AS n", contains="needs more than 200MB of memory")
    assert _rows(run_dir, "SELECT length(repeat('x', 1000)) AS n") == [{"n": 1000}]


def test_the_time_limit_covers_the_whole_query_and_kills_it(run_dir, monkeypatch):
    """Reading the index (here: stuck) was outside the timer, and an interrupt waits for DuckDB to look."""
    monkeypatch.setattr(query, "connect", lambda *args: time.sleep(20))
    _refused(run_dir, "SELECT 1", "--timeout", "0.5", contains="time limit of 0.5 s")


def test_the_time_limit_stops_a_query_that_streams_rows(run_dir):
    """Once rows streamed, a batch always waited in the pipe and the deadline was never looked at: a 2 s limit
    ran 200 s until killed from outside. The reader here is slower than the child, as writing JSON lines is."""
    started = time.monotonic()
    names, rows = query.run_query(run_dir, "SELECT * FROM range(1000000000000)", timeout_s=1.0)
    with pytest.raises(RecordError, match="stopped after the time limit of 1 s"):
        for n, _ in enumerate(rows):
            assert time.monotonic() - started < 30, f"still streaming after 30 s ({n} rows)"
            if n % 100 == 0:
                time.sleep(0.01)
    assert time.monotonic() - started < 10


def test_a_query_process_that_dies_is_one_line(run_dir, monkeypatch):
    monkeypatch.setattr(query, "_confine", lambda *args: os.kill(os.getpid(), signal.SIGKILL))
    _refused(run_dir, "SELECT 1", contains="ended without an answer (killed by signal 9)")


def test_a_row_larger_than_one_message_is_refused_and_large_batches_are_split(run_dir, monkeypatch):
    monkeypatch.setattr(query, "_MESSAGE_BYTES", 4096)
    _refused(run_dir, "SELECT repeat('x', 10000) AS r", contains="a row of the result is larger than")
    assert _rows(run_dir, "SELECT x FROM range(2500) t(x)") == [{"x": x} for x in range(2500)]


# 2. the record's path is read literally


@pytest.fixture(scope="module")
def other_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("other") / "run"
    record(folder, 3, 200)
    return folder


@pytest.mark.parametrize("name", ["run*", "run?", "run[X]", "run[!a]*"])
def test_glob_characters_in_the_path_read_only_that_index(tmp_path, other_dir, name):
    folder = tmp_path / name
    record(folder, 2, 200)
    for sibling in ("runX", "runXY"):  # records (of 3 cycles) that a pattern in the name would match
        shutil.copytree(other_dir / "index", tmp_path / sibling / "index")
    assert _rows(folder, "SELECT count(*) AS n FROM cycles") == [{"n": 2}]
    assert _rows(folder / "index", "SELECT count(*) AS n FROM cycles") == [{"n": 2}]


def test_a_key_value_folder_in_the_path_is_not_a_column(tmp_path):
    """DuckDB's hive partitioning took ``site=elsewhere`` in the path for the site of every row."""
    folder = tmp_path / "site=elsewhere" / "run"
    record(folder, 2, 200)
    assert _rows(folder, "SELECT DISTINCT site FROM cycles") == [{"site": "test-site"}]
    assert _rows(folder, "SELECT DISTINCT typeof(day) AS t FROM cycles") == [{"t": "DATE"}]


# 3. an empty table has its columns


def _describe(folder, table) -> list[tuple[str, str]]:
    return [(r["column_name"], r["column_type"]) for r in _rows(folder, f"DESCRIBE {table}")]


def test_a_record_without_events_answers_over_events(run_dir, quiet_dir):
    assert _rows(quiet_dir, "SELECT kind, count(*) AS n FROM events GROUP BY kind") == []
    assert _rows(quiet_dir, "SELECT c.cycle, e.reason FROM cycles c JOIN events e USING (cycle)") == []
    assert _describe(quiet_dir, "events") == _describe(run_dir, "events")  # the writer's columns, typed alike
    assert [name for name, _ in _describe(quiet_dir, "events")] == [*index.COLUMNS["events"], "day"]


def test_an_index_without_cycles_answers_over_cycles(run_dir, tmp_path):
    writer = IndexWriter(tmp_path / "index", epoch_wall_ns=1_790_000_000_000_000_000)
    writer.add("events", event_row({"t_ns": 5, "kind": "position_clamp", "reason": "test"}, None, {}))  # no context
    writer.flush()
    assert _rows(tmp_path, "SELECT phase, count(*) AS n FROM cycles GROUP BY phase") == []
    fixed = _describe(run_dir, "cycles")
    assert _describe(tmp_path, "cycles") == fixed[:len(index.COLUMNS["cycles"])] + fixed[-1:]  # no features; day
    assert _rows(tmp_path, "SELECT kind, reason, site FROM events") == [
        {"kind": "position_clamp", "reason": "test", "site": None}]
    con = connect(tmp_path / "index")
    assert con.execute("SELECT count(*), count(success) FROM cycles").fetchall() == [(0, 0)]


# 4. EXPLAIN only of a SELECT


WRITES = ["DROP TABLE cycles", "CREATE TABLE z AS SELECT 1", "COPY (SELECT 1) TO '/tmp/cellguard-explain.csv'",
          "INSERT INTO cycles (cycle) VALUES (99)", "DELETE FROM events RETURNING *", "UPDATE cycles SET cycle = 1",
          "CREATE VIEW v AS SELECT 1", "ALTER TABLE cycles RENAME TO c2", "CREATE MACRO m(a) AS a", "SET threads = 1",
          "CREATE OR REPLACE TABLE cycles AS SELECT 1", "TRUNCATE events", "COPY cycles FROM '/etc/passwd'",
          "INSTALL httpfs", "PRAGMA version", "CALL pragma_version()", "CHECKPOINT", "CREATE SEQUENCE s",
          "MERGE INTO cycles USING events ON (cycles.cycle = events.cycle) WHEN MATCHED THEN DELETE"]
SELECTS = ["SELECT 1", "(SELECT count(*) FROM cycles)", "FROM cycles", "WITH a AS (SELECT 1 AS x) SELECT * FROM a",
           "SELECT '(' AS p, ')' AS q", "VALUES (1)", "SELECT 'DROP TABLE cycles' AS s", "DESCRIBE SELECT 1"]
OPTIONS = ["", "ANALYZE", "analyse", "(ANALYZE)", "(FORMAT json)", "(FORMAT json, ANALYZE true)", "(analyze false)"]
GAPS = [" ", "\n", "\t ", " /* é ( */ ", " -- )\n", "/**/"]


def _case(word: str, upper: bool) -> str:
    return word.upper() if upper else word.lower()


@st.composite
def explains(draw, inners):
    gap = st.sampled_from(GAPS)
    option = draw(st.sampled_from(OPTIONS))
    option = draw(gap) + option if option else ""
    text = (f"{draw(st.sampled_from(['', '/* lead */ ']))}{_case('EXPLAIN', draw(st.booleans()))}{option}"
            f"{draw(gap)}{draw(st.sampled_from(inners))}{draw(st.sampled_from(['', ';', ' ; -- end']))}")
    return text


@pytest.fixture(scope="module")
def scratch() -> duckdb.DuckDBPyConnection:
    con = duckdb.connect(config={"threads": 1})
    con.execute("CREATE TABLE cycles AS SELECT 1::BIGINT AS cycle; CREATE TABLE events AS SELECT 1::BIGINT AS cycle")
    con.execute("SET enable_external_access = false")
    return con


def _catalog(con) -> list:
    return con.execute("SELECT database_name, schema_name, table_name, sql, estimated_size FROM duckdb_tables() "
                       "UNION ALL SELECT database_name, schema_name, view_name, sql, 0 FROM duckdb_views() "
                       "WHERE NOT internal ORDER BY ALL").fetchall()


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(case=st.one_of(st.tuples(explains(WRITES), st.just(False)), st.tuples(explains(SELECTS), st.just(True))))
def test_explain_is_accepted_only_of_a_select(scratch, case):
    """EXPLAIN ANALYZE runs what it explains: only a SELECT may get past the check, and running it changes nothing."""
    sql, select = case
    assert duckdb.extract_statements(sql)[0].type == duckdb.StatementType.EXPLAIN  # DuckDB reads it as EXPLAIN
    if select:
        assert query._one_select(sql) == sql
        before = _catalog(scratch)
        scratch.execute(sql).fetchall()
        assert _catalog(scratch) == before
    else:
        with pytest.raises(RecordError, match="^sql: ") as refused:
            query._one_select(sql)
        assert "\n" not in str(refused.value)


@pytest.mark.parametrize("sql", ["EXPLAIN ANALYZE DROP TABLE cycles", "EXPLAIN ANALYZE CREATE TABLE z AS SELECT 1",
                                 "EXPLAIN (ANALYZE) DELETE FROM events",
                                 "EXPLAIN ANALYZE COPY (SELECT 1) TO '{tmp}/x.csv'"])
def test_explain_analyze_of_a_write_is_one_line(run_dir, tmp_path, sql):
    _refused(run_dir, sql.format(tmp=tmp_path), contains='sql: EXPLAIN of "')
    assert list(tmp_path.iterdir()) == []
    rows = _rows(run_dir, "EXPLAIN ANALYZE SELECT count(*) FROM cycles")
    assert rows and rows[0]["explain_key"] == "analyzed_plan"


# 5. faithful JSON


def test_two_columns_of_one_name_are_refused_naming_it(run_dir):
    line = _refused(run_dir, 'SELECT 1 AS a, 2 AS a, 3 AS b, 4 AS "A", 5 AS b', contains="named")
    assert '"a", "b"' in line and '"A"' not in line
    _refused(run_dir, "SELECT * FROM cycles c JOIN events e USING (cycle)", contains='"site"')
    assert _rows(run_dir, 'SELECT 1 AS a, 2 AS "A"') == [{"a": 1, "A": 2}]


def test_nan_and_infinities_are_null_and_the_output_is_json(run_dir):
    rows = _rows(run_dir, "SELECT 'nan'::DOUBLE AS x, 'inf'::DOUBLE AS y, '-inf'::FLOAT AS z, 1.5::DOUBLE AS f, "
                          "[1.5, 'nan'::DOUBLE] AS l, {'k': 'inf'::DOUBLE} AS s, "
                          "MAP {'nan'::DOUBLE: 1.0::DOUBLE} AS m, MAP {2: '-inf'::DOUBLE} AS m2")
    assert rows == [{"x": None, "y": None, "z": None, "f": 1.5, "l": [1.5, None], "s": {"k": None},
                     "m": {"NaN": 1.0}, "m2": {"2": None}}]


_scalars = (st.none() | st.booleans() | st.integers() | st.text() | st.floats(allow_nan=True, allow_infinity=True))
_values = st.recursive(_scalars, lambda inner: st.lists(inner, max_size=4) | st.tuples(inner, inner)
                       | st.dictionaries(_scalars.filter(lambda k: k is not None and not isinstance(k, float))
                                         | st.floats(), inner, max_size=4), max_leaves=20)


def _expected(value):
    """What Python's own JSON makes of ``value`` (it spells a map's keys the same), NaN and infinities null."""
    return json.loads(json.dumps(value), parse_constant=lambda _: None)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(st.text(max_size=5), _values), min_size=1, max_size=5, unique_by=lambda c: c[0]))
def test_every_row_is_strict_json_and_finite_values_survive(columns):
    names, row = [c[0] for c in columns], tuple(c[1] for c in columns)
    line = query.json_line(names, row)
    assert "\n" not in line
    assert json.loads(line, parse_constant=_no_constant) == {n: _expected(v) for n, v in zip(names, row)}


def test_a_reader_that_closes_the_pipe_stops_the_query_quietly(run_dir):
    """``record query ... | head -n 1``: exit 1 without a word before; now 141 as ``cat`` gives, and no child left."""
    import subprocess

    command = [sys.executable, "-c", "from cellguard.cli import app; app()", "record", "query", str(run_dir),
               "SELECT * FROM range(50000000)"]
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert json.loads(proc.stdout.readline()) == {"range": 0}
    proc.stdout.close()
    assert proc.wait(timeout=60) == 141
    assert proc.stderr.read() == b""


# 6. the .mcap file and missing folders


def test_the_record_file_stands_for_its_run_folder(run_dir):
    sql = "SELECT cycle, success FROM cycles ORDER BY cycle"
    assert _rows(run_dir / "record.mcap", sql) == _rows(run_dir, sql) == _rows(run_dir / "index", sql)


def test_a_missing_folder_or_index_is_one_line(tmp_path):
    _refused(tmp_path / "nowhere", "SELECT 1", contains="no such folder")
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "record.mcap").write_bytes(b"")
    _refused(tmp_path / "run" / "record.mcap", "SELECT 1", contains=f"{tmp_path / 'run'}: no index")
