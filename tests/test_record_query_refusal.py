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
    ("INSTALL httpfs", f"sql: INSTALL {EXTENSIONS}"),
    ("force install httpfs FROM community", f"sql: force install {EXTENSIONS}"),  # as written
    ("/* ( */ LOAD '/tmp/x.duckdb_extension'", f"sql: LOAD {EXTENSIONS}"),
    ("TRUNCATE events", "sql: TRUNCATE (read as DELETE) is refused; the query is read-only"),
    ("CHECKPOINT", "sql: CHECKPOINT (read as CALL) is refused; the query is read-only"),
    ("WITH a AS (SELECT 1) DELETE FROM cycles", "sql: WITH (read as DELETE) is refused; the query is read-only"),
    ("DROP TABLE cycles", "sql: DROP TABLE is refused; the query is read-only"),
    ("UPDATE EXTENSIONS", "sql: UPDATE EXTENSIONS is refused; the query is read-only"),
    ("EXPLAIN ANALYZE INSTALL httpfs", "sql: EXPLAIN of an INSTALL statement is refused"),
    ("EXPLAIN ANALYZE UPDATE EXTENSIONS", "sql: EXPLAIN of an UPDATE EXTENSIONS statement is refused"),
    # in the user's letter case (``pragma version`` was refused as "PRAGMA VERSION")
    ("pragma version", "sql: pragma version is refused; the query is read-only"),
    ("Pragma database_list", "sql: Pragma is refused; the query is read-only"),
    ("/* x */ drop   TABLE cycles", "sql: drop TABLE is refused; the query is read-only"),  # not "(read as DROP)"
    ("checkpoint", "sql: checkpoint (read as CALL) is refused; the query is read-only"),
    ("force install httpfs", "sql: force install is refused: extensions are not available in a query"),
    ("explain analyze install httpfs", "sql: explain of an install statement is refused (EXPLAIN ANALYZE runs it)"),
    ("Explain Analyze Update Extensions", "sql: Explain of an Update Extensions statement is refused"),
    ("explain (format json) pragma version", "sql: explain of a pragma version statement is refused"),
])
def test_a_refused_statement_is_named_as_written(sql, line):
    with pytest.raises(RecordError) as refused:
        query._one_select(sql)
    assert str(refused.value).startswith(line), str(refused.value)


def test_install_is_refused_in_one_line(tmp_path):
    record(tmp_path / "run", 2, 100)
    result = CliRunner().invoke(app, ["record", "query", str(tmp_path / "run"), "INSTALL httpfs"])
    assert one_error(result).startswith(f"error: sql: INSTALL {EXTENSIONS}")
