"""Read-only SQL over one record's index: the tables ``cycles`` and ``events``, nothing else.

A query tool on a technician's machine must not read other files, write any file (the record
included), attach databases, fetch extensions or take the machine's memory or time. The query runs
in a child process of its own, killed at the time limit whatever DuckDB is doing (an interrupt waits
for a scalar function such as ``repeat`` to return), and on Linux the OS caps what that process may
allocate (RLIMIT_DATA): DuckDB's ``memory_limit`` counts its buffers, not what a scalar function
allocates (one ``len(range(0, 200000000))`` took 14 GB). In the child, pyarrow reads the index parts,
each by its literal path, into an in-memory DuckDB whose file and network access is off from the
start (no ``read_text``, ``COPY ... TO``, ``ATTACH``, ``INSTALL``), with extension auto-install and
auto-load off, no temporary directory (a query that does not fit fails; DuckDB's default would spill
into ``./.tmp``) and the configuration locked (no ``SET`` gives any of it back). Only one ``SELECT``
(or ``EXPLAIN`` of one) is accepted, so even the in-memory copy is never changed.
"""

from __future__ import annotations

import datetime as dt
import json
import math
import multiprocessing
import pickle
import re
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import duckdb
import pyarrow as pa

from cellguard.errors import RecordError
from cellguard.record.index import TABLES, connect, first_line
from cellguard.record.json_values import plain
from cellguard.record.reader import index_spans
from cellguard.record.scan import require_regular, scan, stated_record_id
from cellguard.record.schemas import not_cellguard
from cellguard.record.writer import INDEX_DIR, RECORD_FILE
from cellguard.threads import start_process

ALLOWED_STATEMENTS = (duckdb.StatementType.SELECT, duckdb.StatementType.EXPLAIN)
MEMORY_LIMIT = "1GB"  # what a query's process may allocate once DuckDB is started (Linux); a query needing more fails
DEFAULT_TIMEOUT_S = 60.0
EXCERPT_CHARS = 60  # the most of a refused statement its refusal quotes
_DUCKDB_SHARE = 0.75  # DuckDB's buffers stay under the process cap, so a big sort or join fails with DuckDB's own error
_THREADS = 2
_UNITS = {"": 1, "K": 1000, "M": 1000**2, "G": 1000**3, "T": 1000**4, "KI": 1 << 10, "MI": 1 << 20, "GI": 1 << 30,
          "TI": 1 << 40}
_BATCH_ROWS = 1000
_MESSAGE_BYTES = 64 << 20  # the most of a result the parent holds at once; a larger single row is refused
# fork: the child starts in milliseconds with everything imported (a spawned one re-imports cellguard, about 1 s)
_START = "fork" if sys.platform.startswith("linux") else "spawn"


def _one_select(sql: str, parse: Callable[[str], list] = duckdb.extract_statements) -> str:
    """The single read statement in ``sql``; anything else is a RecordError naming what was found."""
    try:
        statements = parse(sql)
    except duckdb.Error as exc:
        raise RecordError(f"sql: {first_line(exc)}") from None
    if not statements:
        raise RecordError("sql: the query is empty; write one SELECT over the tables cycles and events")
    if len(statements) > 1:
        raise RecordError(f"sql: {len(statements)} statements given; write one SELECT over cycles and events")
    kind = _kind(statements[0])
    if kind not in ALLOWED_STATEMENTS:
        why = ": extensions are not available in a query" if kind == duckdb.StatementType.LOAD else ""
        raise RecordError(f"sql: {_written(statements[0])} is refused{why}; the query is read-only: one SELECT over "
                          f"the tables cycles and events")
    if kind == duckdb.StatementType.EXPLAIN:
        _explains_a_select(statements[0].query, parse)
    return sql


def _kind(statement) -> duckdb.StatementType | None:
    """DuckDB's type of ``statement``; None for one its Python enum has no member for (UPDATE EXTENSIONS raised
    ValueError, and the refusal was "ValueError: 29 is not a valid StatementType")."""
    try:
        return statement.type
    except ValueError:
        return None


def _written(statement) -> str:
    """What a refusal names: the statement as written from its first word (comments before it left out), quoted,
    and DuckDB's type where none of its leading keywords (at most four) is it: INSTALL is a LOAD statement,
    TRUNCATE a DELETE, CHECKPOINT a CALL, so the type alone misled. Its keywords alone, unquoted, ran into the
    sentence ("sql: explain of an insert into statement is refused") and left out the rest of it."""
    raw = statement.query.encode()  # token positions are byte offsets
    words, start = [], None
    for pos, kind in duckdb.tokenize(statement.query):
        if kind == duckdb.token_type.comment:
            continue
        start = pos if start is None else start
        if kind != duckdb.token_type.keyword or len(words) == 4:
            break
        words.append(re.match(rb"\w*", raw[pos:])[0].decode().upper())
    said = _quoted(raw[start or 0:].decode(errors="replace").strip())
    kind = _kind(statement)
    name = None if kind in (None, duckdb.StatementType.LOAD) else kind.name.replace("_", " ")
    return said if name is None or name in " ".join(words) else f"{said} (read as {name})"


def _quoted(text: str) -> str:
    """``text`` in double quotes with JSON's escapes (its quotes, backslashes and line breaks too), so that it reads
    unambiguously on one line; at most EXCERPT_CHARS characters of it, ``...`` after the quote saying there is
    more."""
    return json.dumps(text[:EXCERPT_CHARS], ensure_ascii=False) + ("..." if len(text) > EXCERPT_CHARS else "")


def _explains_a_select(sql: str, parse: Callable[[str], list]) -> None:
    """RecordError unless the EXPLAIN statement ``sql`` explains one SELECT: EXPLAIN ANALYZE runs what it
    explains, so ``EXPLAIN ANALYZE DROP TABLE cycles`` would drop it. The explained statement starts after
    EXPLAIN and its ANALYZE keyword or its ``(option, ...)`` list (a parenthesised SELECT is tried first)."""
    raw = sql.encode()
    tokens = duckdb.tokenize(sql)  # positions are byte offsets
    ends = [pos for pos, _ in tokens[1:]] + [len(raw)]
    words = [(raw[pos:end].decode(errors="replace").strip(), pos) for (pos, kind), end in zip(tokens, ends)
             if kind != duckdb.token_type.comment]
    cuts = [len(raw)] if len(words) < 2 else [words[1][1]]
    if len(words) > 2 and words[1][0].lower() in ("analyze", "analyse"):
        cuts = [words[2][1]]
    elif len(words) > 2 and words[1][0] == "(":
        depth = 0
        for i, (text, _) in enumerate(words[1:], 1):
            depth += text.count("(") - text.count(")")
            if depth <= 0:
                cuts.append(words[i + 1][1] if i + 1 < len(words) else len(raw))
                break
    found = "nothing"
    for cut in cuts:
        try:
            inner = parse(raw[cut:].decode(errors="replace"))
        except duckdb.Error:
            continue
        if len(inner) != 1:
            found = f"{len(inner)} statements"
        elif _kind(inner[0]) == duckdb.StatementType.SELECT:
            return
        else:
            found = _written(inner[0])
    raise RecordError(f"sql: {words[0][0]} of {found} is refused (EXPLAIN ANALYZE runs it); only EXPLAIN of one "
                      f"SELECT over the tables cycles and events")


def index_folder(path: Path) -> Path:
    """The index folder of ``path``: a run folder's index/ (the folder of a .mcap file, as ``record info`` takes
    the file), else ``path`` itself (an index folder); RecordError if there is no index/ and the record there is
    another tool's MCAP file."""
    path = Path(path)
    try:
        if not path.exists():
            raise RecordError(f"{path}: no such folder; pass a run folder (holding record.mcap and index/) or its "
                              f"index folder")
        run = path.parent if path.is_file() else path
        if (run / INDEX_DIR).is_dir():
            return run / INDEX_DIR
        record = path if path.is_file() else run / RECORD_FILE
    except OSError as exc:  # a name too long, a link loop: one line
        raise RecordError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    foreign = None
    if record.is_file():  # another tool's file: its "no index" pointed at `record recover`, which refuses it
        try:
            layout = scan(record)
            foreign = not_cellguard(record, layout.topics, layout.schema_names)
        except RecordError:
            pass  # an empty or unreadable record: the missing index is said below
    if foreign:
        raise RecordError(foreign)
    return run


def run_query(folder: Path, sql: str, timeout_s: float = DEFAULT_TIMEOUT_S) -> tuple[list[str], Iterator[tuple]]:
    """Column names and rows of one read-only query over the index of ``folder`` (a run folder, its record.mcap or
    its index), run in a child process that is killed after ``timeout_s`` seconds.

    Raises RecordError (one line) for a refused or failing statement, an unreadable index, a result with two
    columns of one name, a query needing more than MEMORY_LIMIT or still running after ``timeout_s`` seconds
    (rows streamed until then stay printed).
    """
    if not 0 < timeout_s <= 86_400:
        raise RecordError(f"--timeout: {_seconds(timeout_s)} s is outside (0, 86400]")
    index = index_folder(folder)
    deadline = time.monotonic() + timeout_s
    ctx = multiprocessing.get_context(_START)
    receiver, sender = ctx.Pipe(duplex=False)
    for stream in (sys.stdout, sys.stderr):  # a forked child must not hold (and flush) the parent's buffered output
        try:
            stream.flush()
        except (AttributeError, OSError, ValueError):
            pass
    child = ctx.Process(target=_serve, args=(index, sql, timeout_s, sender), name="cellguard-query", daemon=True)
    refused = start_process(child)
    sender.close()  # the child's end: when the child dies, the parent reads the end of the pipe
    if refused is not None:  # the OS's process limit, memory (EAGAIN): a traceback before
        receiver.close()
        raise RecordError(f"query: cannot run it: {refused}")
    try:
        _, names = _receive(child, receiver, deadline, timeout_s)
    except BaseException:
        _stop(child, receiver)
        raise
    return names, _rows(child, receiver, deadline, timeout_s)


def _seconds(value: float) -> str:
    """``--timeout``'s value as it is written: the shortest text that reads back as it, without a trailing ``.0``
    (0 was refused as "0.0 s", and 0.1234567 s stopped at "the time limit of 0.123457 s")."""
    return repr(value).removesuffix(".0")


def _rows(child, receiver, deadline: float, timeout_s: float) -> Iterator[tuple]:
    try:
        while True:
            kind, batch = _receive(child, receiver, deadline, timeout_s)
            if kind == "end":
                return
            yield from batch
    finally:
        _stop(child, receiver)


def _receive(child, receiver, deadline: float, timeout_s: float) -> tuple[str, object]:
    """The child's next message; RecordError for its error line, the time limit or a child that died. The deadline
    is checked before the pipe: a child streaming rows always has one waiting (poll(0) is then True)."""
    left = deadline - time.monotonic()
    if left <= 0 or not receiver.poll(left):
        raise RecordError(f"sql: stopped after the time limit of {_seconds(timeout_s)} s (--timeout)")
    try:
        kind, value = pickle.loads(receiver.recv_bytes(_MESSAGE_BYTES))
    except EOFError:
        child.join()
        code = child.exitcode
        how = f"killed by signal {-code}" if code is not None and code < 0 else f"exit code {code}"
        raise RecordError(f"sql: the query ended without an answer ({how}); most likely it needed more than "
                          f"{MEMORY_LIMIT} of memory (a query never writes to disk)") from None
    if kind == "error":
        raise RecordError(value)
    return kind, value


def _stop(child, receiver) -> None:
    if child.is_alive():
        child.kill()  # not an interrupt: DuckDB checks those only between vectors
    child.join()
    receiver.close()


def _serve(index: Path, sql: str, timeout_s: float, sender) -> None:
    """The child: cap itself, load the index, run ``sql`` and send the names, the rows in batches, then "end";
    or one error line. Nothing is written to stdout."""
    try:
        con = duckdb.connect(config=_config())
        _cap(timeout_s)  # after the connection: its idle threads' stacks are not the query's memory
        _confine(con, index, sql)
        result = con.execute(sql)
        names = [d[0] for d in result.description]
        twice = [n for n in dict.fromkeys(names) if names.count(n) > 1]
        if twice:
            raise RecordError(f"sql: more than one column is named {', '.join(json.dumps(n) for n in twice)}; "
                              f"name each column once (... AS another_name): a JSON object holds one value a name")
        _send(sender, ("names", names))
        while batch := result.fetchmany(_BATCH_ROWS):
            _send_rows(sender, batch)
        _send(sender, ("end", None))
    except (BrokenPipeError, ConnectionResetError):
        pass  # the parent stopped reading (its time limit, a closed stdout)
    except BaseException as exc:  # noqa: BLE001 - every failure becomes the parent's one error line
        try:
            _send(sender, ("error", _message(exc)))
        except (BrokenPipeError, ConnectionResetError):
            pass


def _send(sender, message: tuple) -> None:
    sender.send_bytes(pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL))


def _send_rows(sender, batch: list[tuple]) -> None:
    """A batch in one message, or row by row when that would be larger than _MESSAGE_BYTES."""
    data = pickle.dumps(("rows", batch), protocol=pickle.HIGHEST_PROTOCOL)
    if len(data) <= _MESSAGE_BYTES:
        sender.send_bytes(data)
        return
    for row in batch:
        data = pickle.dumps(("rows", [row]), protocol=pickle.HIGHEST_PROTOCOL)
        if len(data) > _MESSAGE_BYTES:
            raise RecordError(f"sql: a row of the result is larger than {_MESSAGE_BYTES >> 20} MB; select less of it")
        sender.send_bytes(data)


def _cap(timeout_s: float) -> None:
    """Limit the child's memory and CPU (Linux). RLIMIT_DATA counts the heap and every private writable
    mapping, which is where DuckDB's and malloc's memory comes from; pyarrow's mimalloc reserved its arena at
    import (counted already), so pyarrow is switched to malloc. The CPU limit is a backstop for a parent killed
    before it could kill the child at the time limit."""
    import pyarrow as pa

    pa.set_memory_pool(pa.system_memory_pool())
    pa.set_cpu_count(1)
    pa.set_io_thread_count(1)
    try:
        import resource
    except ImportError:  # not POSIX: the time limit still holds
        return
    data = _vm_data_bytes()
    if data is not None:
        _lower(resource, resource.RLIMIT_DATA, data + _bytes(MEMORY_LIMIT))
    _lower(resource, resource.RLIMIT_CPU, math.ceil(timeout_s) * (_THREADS + 2) + 1)


def _lower(resource, which: int, value: int) -> None:
    soft, hard = resource.getrlimit(which)
    value = value if hard == resource.RLIM_INFINITY else min(value, hard)
    resource.setrlimit(which, (value, value))


def _vm_data_bytes() -> int | None:
    try:
        with open("/proc/self/status") as f:
            return next(int(line.split()[1]) * 1024 for line in f if line.startswith("VmData:"))
    except (OSError, StopIteration, ValueError, IndexError):
        return None


def _config() -> dict:
    """DuckDB's settings for a query: few threads, memory under MEMORY_LIMIT, nowhere to spill, no extension."""
    return {"threads": _THREADS, "memory_limit": f"{int(_bytes(MEMORY_LIMIT) * _DUCKDB_SHARE)}B", "temp_directory": "",
            "autoinstall_known_extensions": False, "autoload_known_extensions": False,
            "allow_community_extensions": False}


def _bytes(size: str) -> int:
    """Bytes in a size as DuckDB writes it ("1GB" is 10^9 bytes, "1GiB" 2^30)."""
    match = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*([KMGT]I?)?B?\s*", size.upper())
    if match is None:
        raise ValueError(f"{size!r} is not a size such as 1GB")
    return int(float(match[1]) * _UNITS[match[2] or ""])


def _confine(con: duckdb.DuckDBPyConnection, index: Path, sql: str) -> None:
    """Check ``sql``, then copy the index into ``con`` (in memory) with every way out of it switched off and locked."""
    for setting in ("enable_progress_bar = false", "enable_external_access = false"):  # pyarrow reads the parts
        con.execute(f"SET {setting}")
    _one_select(sql, con.extract_statements)
    for table in TABLES:  # the parts connect() reads: a FIFO would block until the time limit
        for part in (index / table).glob("day=*/*.parquet"):
            require_regular(part, "an index part")
    record = index.parent / RECORD_FILE  # a run folder's index/ is checked against the run's record id
    record_id = stated_record_id(record) if index.name == INDEX_DIR and record.is_file() else None
    connect(index, con, record_id)
    try:
        for table in TABLES:  # copy the views' rows in, so that the query reads memory only
            con.execute(f"CREATE TABLE {table}_copy AS SELECT * FROM {table}")
            con.unregister(table)
            con.execute(f"ALTER TABLE {table}_copy RENAME TO {table}")
        _out_of_span(con, index, record_id)
    except duckdb.OutOfMemoryException:
        raise RecordError(f"{index}: the index needs more than {MEMORY_LIMIT} of memory; query a shorter "
                          f"record") from None
    except duckdb.Error as exc:
        raise RecordError(f"{index}: the index cannot be read ({first_line(exc)}); "
                          f"`cellguard record recover` rebuilds it from the record") from None
    con.execute("SET lock_configuration = true")


def _out_of_span(con: duckdb.DuckDBPyConnection, index: Path, record_id: str | None) -> None:
    """An event lies in no cycle where it lies outside the span of the cycle it is stamped with, as ``Record.events``
    reads it, by the same spans (``index_spans``: only parts naming this record, spans closed; an unnamed part an
    older run left beside it is in the cycles table, not in these). A record written before the recorder stamped
    events after a cycle's end with none has that cycle in its index rows."""
    spans = index_spans(index, record_id)
    if not spans:
        return
    starts, ends = zip(*spans.values())
    con.register("span", pa.table({"cycle": list(spans), "t_start_ns": starts, "t_end_ns": ends}))
    con.execute("UPDATE events SET cycle = NULL FROM span WHERE events.cycle = span.cycle "
                "AND (events.t_ns < span.t_start_ns OR events.t_ns > span.t_end_ns)")
    con.unregister("span")


def _message(exc: BaseException) -> str:
    """The parent's one error line for what stopped the child."""
    if isinstance(exc, RecordError):
        return str(exc)
    if isinstance(exc, (MemoryError, duckdb.OutOfMemoryException)) or "bad_alloc" in str(exc) \
            or "bad allocation" in str(exc):
        return (f"sql: the query needs more than {MEMORY_LIMIT} of memory (a query never writes to disk); "
                f"select fewer rows or columns")
    if isinstance(exc, duckdb.Error):
        return f"sql: {first_line(exc)}"
    return f"sql: {type(exc).__name__}: {first_line(exc)}"


def json_line(names: list[str], row: tuple) -> str:
    """One row as a JSON object, valid JSON always: NaN and infinities (JSON has no word for them) are null, infinite
    dates and timestamps too, a map's keys are strings (an infinite one named: ``_key_text``); anything else JSON has
    no type for is its text."""
    try:
        return json.dumps({name: plain(value, _key_text) for name, value in zip(names, row)}, default=_text,
                          allow_nan=False)
    except RecursionError:
        raise RecordError("sql: a value of the result is nested too deeply to write as JSON") from None


# how DuckDB hands Python -infinity and infinity, and DuckDB's own text for them ('infinity'::DATE::VARCHAR)
_ENDS = {dt.date.min: "-infinity", dt.date.max: "infinity", dt.datetime.min: "-infinity", dt.datetime.max: "infinity"}


def _text(value: object) -> str | None:
    """A value JSON has no type for as its text; an infinite date or timestamp null, as an infinite number is. DuckDB
    hands infinity over as Python's last date ('infinity'::TIMESTAMP printed 9999-12-31 23:59:59.999999, a date
    never recorded), so Python's first and last dates themselves read as null too: the row cannot tell them apart."""
    return None if isinstance(value, dt.date) and value in _ENDS else str(value)


def _key_text(key: object) -> str:
    """A map's key that JSON has no type for as its text, an infinite date or timestamp as DuckDB writes it
    (``infinity``, ``-infinity``), as a NaN or infinite number key keeps its name (``NaN``, ``Infinity``): a key
    cannot be null (two such keys would be one), and 9999-12-31 is a date never recorded."""
    return _ENDS.get(key) or str(key)  # a key is hashable; a date and a datetime are never equal
