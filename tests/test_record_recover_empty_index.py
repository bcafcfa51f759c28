"""A record with no finished cycle and no event (a run killed in its first cycle) recovers with an index whose tables
have their columns and no rows: `record query` answers 0 rows. Its index had no part at all, and `record query`
refused it, pointing back at `record recover`."""

from __future__ import annotations

import json

import pyarrow.parquet as pq
from record_synth import record
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.record.index import COLUMNS, TABLES
from cellguard.record.reader import open_record

runner = CliRunner()


def test_a_record_killed_in_its_first_cycle_recovers_with_an_index_query_answers(tmp_path):
    whole = tmp_path / "whole"
    record(whole, 1, 1500)
    killed = tmp_path / "killed"
    killed.mkdir()
    data = (whole / "record.mcap").read_bytes()
    (killed / "record.mcap").write_bytes(data[: len(data) // 3])  # cut before the cycle's end marker
    with open_record(killed) as rec:
        assert rec.health().truncated and not list(rec.cycles()) and not list(rec.events())
    result = runner.invoke(app, ["record", "recover", str(killed), "-o", str(tmp_path / "rec")])
    assert result.exit_code == 0, result.output
    for table in TABLES:
        parts = list((tmp_path / "rec/index" / table).glob("day=*/part-*.parquet"))
        assert len(parts) == 1 and pq.read_table(parts[0]).num_rows == 0, parts
        assert tuple(pq.read_schema(parts[0]).names) == COLUMNS[table]
    for sql in ("SELECT count(*) AS n FROM cycles", "SELECT count(*) AS n FROM events"):
        result = runner.invoke(app, ["record", "query", str(tmp_path / "rec"), sql])
        assert result.exit_code == 0 and json.loads(result.stdout) == {"n": 0}, result.output
    result = runner.invoke(app, ["record", "query", str(tmp_path / "rec"), "SELECT cycle, phase, success FROM cycles"])
    assert result.exit_code == 0 and result.stdout == "", result.output


def test_a_table_with_rows_gets_no_empty_part_beside_them(tmp_path):
    record(tmp_path / "run", 2, 300)  # cycles, and no event
    cycles = list((tmp_path / "run/index/cycles").glob("day=*/part-*.parquet"))
    events = list((tmp_path / "run/index/events").glob("day=*/part-*.parquet"))
    assert len(cycles) == 1 and pq.read_table(cycles[0]).num_rows == 2
    assert len(events) == 1 and pq.read_table(events[0]).num_rows == 0
