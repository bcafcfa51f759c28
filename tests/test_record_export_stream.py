"""``record export`` writes a record a part at a time: it built the whole long table first, 4.2 times the record's
size in memory (1,655 MB for a 391 MB record; a week's record was killed for memory). The file is what the whole
table gave: the same CSV bytes, the same Parquet rows and schema, damaged and out-of-order records included."""

from __future__ import annotations

import io
import shutil

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq
import pytest
from cli_util import one_error
from record_synth import JOINTS, FullRateAltered, record, rewrite
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.record import export
from cellguard.record.reader import UnorderedTicks, open_record
from cellguard.record.schemas import TICK_FIELDS, TICKS

runner = CliRunner()
CYCLE_TICKS = 1000
PART_ROWS = 900  # small, so that the synthetic record's export takes many parts


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """6 cycles at 1 kHz; an event in cycle 2 keeps 10 s of full rate before it and some after, overlapping the
    decimated stream (ticks at one time in both), and a stretch of decimated ticks alone after it."""
    out = tmp_path_factory.mktemp("rec")
    record(out, 6, CYCLE_TICKS, events={2500: "position_clamp"})
    return out


@pytest.fixture
def parts(monkeypatch):
    """The number of rows of each table handed to a writer."""
    rows = []
    write_csv, write_table = pacsv.write_csv, pq.ParquetWriter.write_table
    monkeypatch.setattr(pacsv, "write_csv",
                        lambda table, *a, **k: rows.append(table.num_rows) or write_csv(table, *a, **k))
    monkeypatch.setattr(pq.ParquetWriter, "write_table",
                        lambda self, table, *a, **k: rows.append(table.num_rows) or write_table(self, table, *a, **k))
    monkeypatch.setattr(export, "PART_ROWS", PART_ROWS, raising=False)
    return rows


def _export(folder, target, *args) -> int:
    result = runner.invoke(app, ["record", "export", str(folder), "-o", str(target), *args])
    assert result.exit_code == 0, result.output
    return int(result.output.split()[0])


def _whole(folder, rate: str) -> pa.Table:
    """The long table as export built it whole, from the reader's ticks."""
    with open_record(folder) as rec:
        return export.ticks_table(rec.ticks(rate=rate))


def _csv(table: pa.Table) -> bytes:
    out = io.BytesIO()
    pacsv.write_csv(table.set_column(2, "joint", table["joint"].cast(pa.string())), out)
    return out.getvalue()


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_the_writer_is_handed_a_part_at_a_time_not_the_whole_record(recorded, tmp_path, parts, fmt):
    rows = _export(recorded, tmp_path / f"t.{fmt}", "--format", fmt)
    with open_record(recorded) as rec:
        ticks = rec.ticks()
    assert rows == len(ticks) * len(JOINTS) == sum(parts) > 6 * PART_ROWS
    assert max(parts) <= PART_ROWS + 100 * len(JOINTS)  # a part, and a batch of 100 ms of ticks at most
    assert max(parts) < CYCLE_TICKS * len(JOINTS)  # under one cycle's rows, whatever the record's length


@pytest.mark.parametrize("rate", ["all", "decimated", "full"])
def test_the_file_is_the_whole_tables(recorded, tmp_path, parts, rate):
    whole = _whole(recorded, rate)
    assert _export(recorded, tmp_path / "t.csv", "--rate", rate) == whole.num_rows
    assert len(parts) > 1
    assert (tmp_path / "t.csv").read_bytes() == _csv(whole)
    assert _export(recorded, tmp_path / "t.parquet", "--rate", rate, "--format", "parquet") == whole.num_rows
    written = pq.read_table(tmp_path / "t.parquet")
    assert written.schema == whole.schema and written.equals(whole)


def test_the_rows_are_the_readers_ticks_once_each_by_time(recorded, tmp_path, parts):
    """Against the reader's arrays, not the table built from them: each tick once, in time order, every field."""
    _export(recorded, tmp_path / "t.csv")
    table = pacsv.read_csv(tmp_path / "t.csv")
    with open_record(recorded) as rec:
        ticks = rec.ticks()
    t = table["t_ns"].to_numpy()
    assert np.all(np.diff(t[::len(JOINTS)]) > 0) and len(np.unique(t)) == len(ticks) > 6 * CYCLE_TICKS / 20
    assert np.array_equal(t, np.repeat(ticks.t_ns, len(JOINTS)))
    assert np.array_equal(table["cycle"].to_numpy(), np.repeat(ticks.cycle, len(JOINTS)))
    assert table["joint"].to_pylist() == list(JOINTS) * len(ticks)
    for name in TICK_FIELDS:
        assert np.array_equal(table[name].to_numpy(), getattr(ticks, name).reshape(-1)), name


def _batch_edit(topic: str, number: int, change):
    """An ``edit_bytes`` changing the ``number``-th message of ``topic`` (as the file holds them) by ``change``."""
    seen = {"n": 0}

    def edit(at: str, data: bytes) -> bytes:
        if at != topic:
            return data
        seen["n"] += 1
        return TICKS.encode(change(TICKS.decode(data))) if seen["n"] == number else data
    return edit


def test_a_batch_reaching_back_in_time_is_sorted_in_as_before(recorded, tmp_path, parts):
    """Not as the recorder writes: a late decimated batch whose ticks lie 4 s earlier, some at times already in the
    file. Its ticks are sorted in, one per time, as the whole table had them."""
    def back(batch):
        return {**batch, "t_ns": batch["t_ns"] - 4_000_000_000 + 7}

    rewrite(recorded, tmp_path / "run", edit_bytes=_batch_edit("/ticks/decimated", 50, back))
    with open_record(tmp_path / "run") as rec, pytest.raises(UnorderedTicks):
        list(rec.tick_parts("all", export.PART_ROWS))
    whole = _whole(tmp_path / "run", "all")
    assert _export(tmp_path / "run", tmp_path / "t.csv") == whole.num_rows
    assert (tmp_path / "t.csv").read_bytes() == _csv(whole)


def test_a_batch_naming_other_joints_is_skipped_and_reported_as_before(recorded, tmp_path, parts):
    def renamed(batch):
        return {**batch, "joints": [*batch["joints"][:-1], "other"]}

    rewrite(recorded, tmp_path / "run", edit_bytes=_batch_edit("/ticks/full", 3, renamed))
    result = runner.invoke(app, ["record", "export", str(tmp_path / "run"), "-o", str(tmp_path / "t.csv")])
    whole = _whole(tmp_path / "run", "all")
    assert result.exit_code == 1 and f"{whole.num_rows} rows written" in result.output
    assert "1 /ticks/full message(s) malformed, skipped" in result.output
    assert (tmp_path / "t.csv").read_bytes() == _csv(whole)


def test_a_cut_record_exports_what_it_holds_as_before(recorded, tmp_path, parts):
    (tmp_path / "run").mkdir()
    data = (recorded / "record.mcap").read_bytes()
    (tmp_path / "run" / "record.mcap").write_bytes(data[:len(data) * 2 // 3])
    result = runner.invoke(app, ["record", "export", str(tmp_path / "run"), "-o", str(tmp_path / "t.pq"),
                                 "--format", "parquet"])
    whole = _whole(tmp_path / "run", "all")
    assert result.exit_code == 1 and f"{whole.num_rows} rows written" in result.output and "truncated" in result.output
    assert 0 < whole.num_rows and pq.read_table(tmp_path / "t.pq").equals(whole)


def test_a_record_without_ticks_writes_the_header_alone(recorded, tmp_path):
    rewrite(recorded, tmp_path / "run", edit_bytes=lambda topic, data: b"" if topic.startswith("/ticks/") else data)
    result = runner.invoke(app, ["record", "export", str(tmp_path / "run"), "-o", str(tmp_path / "t.csv")])
    assert result.exit_code == 1 and result.output.startswith("0 rows written") and "malformed" in result.output
    assert (tmp_path / "t.csv").read_bytes() == _csv(_whole(tmp_path / "run", "all"))
    assert (tmp_path / "t.csv").read_text().count("\n") == 1


def test_a_record_that_cannot_be_read_leaves_nothing(recorded, tmp_path):
    """The first part is read before the file is made: a context of a newer format leaves no folder, no file."""
    shutil.copytree(recorded, tmp_path / "run")
    rewrite(recorded, tmp_path / "run", metadata={"cellguard": {"record_version": "1"}},
            edit=lambda topic, d: {**d, "record_version": 99} if topic == "/context" else d)
    result = runner.invoke(app, ["record", "export", str(tmp_path / "run"), "-o", str(tmp_path / "new" / "t.csv")])
    assert "newer than this cellguard reads" in one_error(result)
    assert not (tmp_path / "new").exists()


def test_of_ticks_at_one_time_the_decimated_then_the_first_read_is_kept(recorded, tmp_path, parts):
    """The recorder writes the same values to both streams, so which copy of a tick was kept showed nowhere. Here
    each full-rate batch's q_ref is raised by 1000 times its number, and batch 5 reaches half a batch back over
    batch 4: the decimated copy wins, then the one read first, as in the whole table."""
    edit = FullRateAltered(overlap_at=5)
    rewrite(recorded, tmp_path / "run", edit_bytes=edit)
    whole = _whole(tmp_path / "run", "all")
    assert _export(tmp_path / "run", tmp_path / "t.csv") == whole.num_rows
    assert (tmp_path / "t.csv").read_bytes() == _csv(whole)
    table = pacsv.read_csv(tmp_path / "t.csv")
    t, q_ref = table["t_ns"].to_numpy(), table["q_ref"].to_numpy()
    with open_record(tmp_path / "run") as rec:
        decimated = rec.ticks(rate="decimated").t_ns
    assert np.all(np.abs(q_ref[np.isin(t, decimated)]) < 500)  # the decimated copies
    overlap = np.isin(t, edit.overlap) & ~np.isin(t, decimated)
    assert overlap.any() and np.all((q_ref[overlap] > 3500) & (q_ref[overlap] < 4500))  # batch 4's, read first


@pytest.mark.parametrize("rate, fmt", [("bogus", "csv"), ("all", "xlsx")])
def test_an_unknown_rate_or_format_is_refused_before_anything_is_written(recorded, tmp_path, rate, fmt):
    """Called from Python: an unknown rate wrote a header-only csv (no stream matched), an unknown format a csv."""
    from cellguard.errors import RecordError

    with open_record(recorded) as rec, pytest.raises(RecordError, match="the rates are decimated, full, all"):
        export.write_ticks(rec, tmp_path / "t.out", fmt, rate=rate)
    assert not (tmp_path / "t.out").exists()
