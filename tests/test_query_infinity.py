"""`record query` prints an infinite date or timestamp as null, as it does an infinite number: DuckDB hands it to
Python as Python's last (or first) date, and `SELECT 'infinity'::TIMESTAMP` printed {"t": "9999-12-31 23:59:59.999999"},
a date never recorded."""

from __future__ import annotations

import json

import pytest
from record_synth import record
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import RecordError
from cellguard.record.query import run_query

runner = CliRunner()


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("run")
    record(folder, 2, 50)
    return folder


def test_infinite_dates_and_timestamps_are_null_at_any_depth_and_finite_ones_text(run):
    sql = ("SELECT 'infinity'::TIMESTAMP AS t, '-infinity'::TIMESTAMP AS t0, 'infinity'::DATE AS d, "
           "'-infinity'::DATE AS d0, 'infinity'::TIMESTAMPTZ AS tz, 'infinity'::TIMESTAMP_NS AS ns, "
           "['infinity'::DATE, DATE '2026-01-02'] AS l, {'a': 'infinity'::TIMESTAMP} AS s, 'infinity'::DOUBLE AS x, "
           "DATE '2026-01-02' AS ok, min(day) AS day FROM cycles")
    result = runner.invoke(app, ["record", "query", str(run), sql])
    assert result.exit_code == 0, result.output
    row = json.loads(result.stdout)
    assert row == {"t": None, "t0": None, "d": None, "d0": None, "tz": None, "ns": None, "l": [None, "2026-01-02"],
                   "s": {"a": None}, "x": None, "ok": "2026-01-02", "day": "2026-09-21"}


def test_a_query_process_the_os_refuses_is_one_line(run, monkeypatch):
    """The query's worker process refused (EAGAIN from the fork: the process limit) was a traceback."""
    import errno
    import multiprocessing.util
    import os

    def refused(*_):
        raise BlockingIOError(errno.EAGAIN, "Resource temporarily unavailable")

    monkeypatch.setattr(os, "fork", refused)
    monkeypatch.setattr(multiprocessing.util, "spawnv_passfds", refused)
    with pytest.raises(RecordError, match=r"^query: cannot run it: its process 'cellguard-query' could not start"):
        run_query(run, "SELECT 1 AS x")
