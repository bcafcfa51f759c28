"""A refused ``record query`` statement is quoted as written, from its first word, with JSON's escapes: its
keywords alone, unquoted, ran into the sentence ("sql: explain of an insert into statement is refused", "sql: drop
table is refused" for ``drop\\n  table "my table"``) and left out what they applied to. A long one is cut, "..."
after the quote saying so."""

from __future__ import annotations

import pytest
from record_synth import record
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import RecordError
from cellguard.record import query

READ_ONLY = "; the query is read-only: one SELECT over the tables cycles and events"
EXPLAIN = " is refused (EXPLAIN ANALYZE runs it); only EXPLAIN of one SELECT over the tables cycles and events"
LONG = "CREATE TABLE t AS SELECT 'a long literal that goes on' AS a, 2 AS b, 3 AS c"


@pytest.mark.parametrize(("sql", "said"), [
    ('drop\n  table "my table"', r'sql: "drop\n  table \"my table\"" is refused' + READ_ONLY),
    ("ATTACH 'site.db' AS s", """sql: "ATTACH 'site.db' AS s" is refused""" + READ_ONLY),
    ("COPY cycles TO '/tmp/out put.csv'", """sql: "COPY cycles TO '/tmp/out put.csv'" is refused""" + READ_ONLY),
    ("/* lead */ TRUNCATE events ;", 'sql: "TRUNCATE events ;" (read as DELETE) is refused' + READ_ONLY),
    ("-- why\nPRAGMA\tdatabase_list", r'sql: "PRAGMA\tdatabase_list" is refused' + READ_ONLY),
    ("SET x = 'C:\\tmp'", r"""sql: "SET x = 'C:\\tmp'" is refused""" + READ_ONLY),
    ("INSTALL httpfs", 'sql: "INSTALL httpfs" is refused: extensions are not available in a query' + READ_ONLY),
    ("explain analyze\ninsert into cycles values (1)", 'sql: explain of "insert into cycles values (1)"' + EXPLAIN),
    ("EXPLAIN ANALYZE TRUNCATE events", 'sql: EXPLAIN of "TRUNCATE events" (read as DELETE)' + EXPLAIN),
    (LONG, f'sql: "{LONG[:60]}"... is refused' + READ_ONLY),  # query.EXCERPT_CHARS
])
def test_a_refusal_quotes_the_statement_as_written(sql, said):
    with pytest.raises(RecordError) as refused:
        query._one_select(sql)
    assert str(refused.value) == said


def test_a_refusal_on_the_command_line_is_one_line_with_its_escapes(tmp_path):
    record(tmp_path / "run", 2, 100)
    sql = "attach\n'x.db' AS \"\x1b[31mred\""
    result = CliRunner().invoke(app, ["record", "query", str(tmp_path / "run"), sql])
    assert result.exit_code == 2 and result.output == (r'''error: sql: "attach\n'x.db' AS \"\u001b[31mred\"" is '''
                                                       f"refused{READ_ONLY}\n")
