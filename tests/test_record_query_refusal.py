"""A refused ``record query`` statement is named as it was written: DuckDB's statement type is not what the user
wrote (INSTALL is a LOAD statement, TRUNCATE a DELETE, CHECKPOINT a CALL), and one type its Python enum lacks
(UPDATE EXTENSIONS) was refused as "ValueError: 29 is not a valid StatementType"."""

from __future__ import annotations

import pytest
from cli_util import one_error
from record_synth import record
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import RecordError
from cellguard.record import query

EXTENSIONS = "is refused: extensions are not available in a query; the query is read-only"


@pytest.mark.parametrize(("sql", "line"), [
    ("INSTALL httpfs", f'sql: "INSTALL httpfs" {EXTENSIONS}'),
    ("force install httpfs FROM community", f'sql: "force install httpfs FROM community" {EXTENSIONS}'),  # as written
    ("/* ( */ LOAD '/tmp/x.duckdb_extension'", f"""sql: "LOAD '/tmp/x.duckdb_extension'" {EXTENSIONS}"""),
    ("TRUNCATE events", 'sql: "TRUNCATE events" (read as DELETE) is refused; the query is read-only'),
    ("CHECKPOINT", 'sql: "CHECKPOINT" (read as CALL) is refused; the query is read-only'),
    ("WITH a AS (SELECT 1) DELETE FROM cycles",
     'sql: "WITH a AS (SELECT 1) DELETE FROM cycles" (read as DELETE) is refused; the query is read-only'),
    ("DROP TABLE cycles", 'sql: "DROP TABLE cycles" is refused; the query is read-only'),
    ("UPDATE EXTENSIONS", 'sql: "UPDATE EXTENSIONS" is refused; the query is read-only'),
    ("EXPLAIN ANALYZE INSTALL httpfs", 'sql: EXPLAIN of "INSTALL httpfs" is refused'),
    ("EXPLAIN ANALYZE UPDATE EXTENSIONS", 'sql: EXPLAIN of "UPDATE EXTENSIONS" is refused'),
    # in the user's letter case (``pragma version`` was refused as "PRAGMA VERSION")
    ("pragma version", 'sql: "pragma version" is refused; the query is read-only'),
    ("Pragma database_list", 'sql: "Pragma database_list" is refused; the query is read-only'),
    ("/* x */ drop   TABLE cycles", 'sql: "drop   TABLE cycles" is refused; the query is read-only'),  # no read-as
    ("checkpoint", 'sql: "checkpoint" (read as CALL) is refused; the query is read-only'),
    ("force install httpfs", 'sql: "force install httpfs" is refused: extensions are not available in a query'),
    ("explain analyze install httpfs", 'sql: explain of "install httpfs" is refused (EXPLAIN ANALYZE runs it)'),
    ("Explain Analyze Update Extensions", 'sql: Explain of "Update Extensions" is refused'),
    ("explain (format json) pragma version", 'sql: explain of "pragma version" is refused'),
])
def test_a_refused_statement_is_named_as_written(sql, line):
    with pytest.raises(RecordError) as refused:
        query._one_select(sql)
    assert str(refused.value).startswith(line), str(refused.value)


def test_install_is_refused_in_one_line(tmp_path):
    record(tmp_path / "run", 2, 100)
    result = CliRunner().invoke(app, ["record", "query", str(tmp_path / "run"), "INSTALL httpfs"])
    assert one_error(result).startswith(f'error: sql: "INSTALL httpfs" {EXTENSIONS}')
