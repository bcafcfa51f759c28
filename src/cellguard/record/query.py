"""Read-only SQL over one record's index: the tables ``cycles`` and ``events``, nothing else.

A query tool on a technician's machine must not read other files, write any file (the record
included), attach databases or fetch extensions. DuckDB enforces that itself: the index is copied
into an in-memory database first, then external access is switched off (no file or network
access at all, so no ``read_text``, ``COPY ... TO``, ``ATTACH``, ``INSTALL``), extension
auto-install and auto-load are off, memory is capped with no temporary directory (a query that
does not fit fails; DuckDB's default would spill into ``./.tmp`` in the current folder) and the
configuration is locked (no ``SET`` gives any of it back). On top, only one ``SELECT`` (or
``EXPLAIN``) statement is accepted, so even the in-memory copy cannot be changed, and a query
that runs past its time limit is interrupted.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from pathlib import Path

import duckdb

from cellguard.errors import RecordError
from cellguard.record.index import TABLES, connect
from cellguard.record.scan import require_regular

ALLOWED_STATEMENTS = (duckdb.StatementType.SELECT, duckdb.StatementType.EXPLAIN)
MEMORY_LIMIT = "1GB"  # DuckDB's own memory for one query
DEFAULT_TIMEOUT_S = 60.0
_BATCH_ROWS = 1000


def _one_select(sql: str) -> str:
    """The single read statement in ``sql``; anything else is a RecordError naming what was found."""
    try:
        statements = duckdb.extract_statements(sql)
    except duckdb.Error as exc:
        raise RecordError(f"sql: {_first_line(exc)}") from None
    if not statements:
        raise RecordError("sql: the query is empty; write one SELECT over the tables cycles and events")
    if len(statements) > 1:
        raise RecordError(f"sql: {len(statements)} statements given; write one SELECT over cycles and events")
    kind = statements[0].type
    if kind not in ALLOWED_STATEMENTS:
        raise RecordError(f"sql: {kind.name} statements are refused; the query is read-only: one SELECT over "
                          f"the tables cycles and events")
    return sql


def _confined(index: Path) -> duckdb.DuckDBPyConnection:
    """An in-memory copy of the index with every way out of it switched off and locked."""
    for table in TABLES:  # the parts connect() reads: a FIFO would block the copy, which --timeout does not cover
        for part in (index / table).glob("day=*/*.parquet"):
            require_regular(part, "an index part")
    con = None
    try:
        con = connect(index)
        for setting in (f"memory_limit = '{MEMORY_LIMIT}'", "temp_directory = ''"):  # nothing spills to disk
            con.execute(f"SET {setting}")
        for table in TABLES:  # copy the views' rows in while files can still be read
            con.execute(f"CREATE TABLE {table}_copy AS SELECT * FROM {table}")
            con.execute(f"DROP VIEW {table}")
            con.execute(f"ALTER TABLE {table}_copy RENAME TO {table}")
    except duckdb.Error as exc:
        if con is not None:
            con.close()
        raise RecordError(f"{index}: the index cannot be read ({_first_line(exc)}); "
                          f"`cellguard record recover` rebuilds it from the record") from None
    for setting in ("autoinstall_known_extensions = false", "autoload_known_extensions = false",
                    "allow_community_extensions = false", "enable_external_access = false",
                    "lock_configuration = true"):
        con.execute(f"SET {setting}")
    return con


def run_query(folder: Path, sql: str, timeout_s: float = DEFAULT_TIMEOUT_S) -> tuple[list[str], Iterator[tuple]]:
    """Column names and rows of one read-only query over the index of ``folder`` (a run folder or its index).

    Raises RecordError (one line) for a refused or failing statement, an unreadable index, or a
    query still running after ``timeout_s`` seconds (rows streamed until then stay printed).
    """
    from cellguard.record.writer import INDEX_DIR

    if not 0 < timeout_s <= 86_400:
        raise RecordError(f"--timeout: {timeout_s} s is outside (0, 86400]")
    sql = _one_select(sql)
    folder = Path(folder)
    con = _confined(folder / INDEX_DIR if (folder / INDEX_DIR).is_dir() else folder)
    timer = threading.Timer(timeout_s, con.interrupt)
    timer.daemon = True
    timer.start()
    try:
        result = con.execute(sql)
    except BaseException as exc:
        timer.cancel()
        con.close()
        raise _query_error(exc, timeout_s) from None
    return [d[0] for d in result.description], _rows(con, result, timer, timeout_s)


def _rows(con, result, timer: threading.Timer, timeout_s: float) -> Iterator[tuple]:
    try:
        while batch := result.fetchmany(_BATCH_ROWS):
            yield from batch
    except duckdb.Error as exc:
        raise _query_error(exc, timeout_s) from None
    finally:
        timer.cancel()
        con.close()


def _query_error(exc: BaseException, timeout_s: float) -> BaseException:
    if isinstance(exc, duckdb.InterruptException):
        return RecordError(f"sql: stopped after the time limit of {timeout_s:g} s (--timeout)")
    if isinstance(exc, duckdb.OutOfMemoryException):
        return RecordError(f"sql: the query needs more than {MEMORY_LIMIT} of memory (a query never writes to "
                           f"disk); select fewer rows or columns")
    if isinstance(exc, duckdb.Error):
        return RecordError(f"sql: {_first_line(exc)}")
    return exc


def _first_line(exc: Exception) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__
