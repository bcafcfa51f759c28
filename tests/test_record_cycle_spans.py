"""A cycle's span has one source for ``ticks(cycle=N)`` and for each tick's cycle: ``cycle_spans``, the index's row
where the index has the cycle, else the markers, of a cycle marked twice the last. A window read takes the spans from
the index (read once, in bulk) and reads the markers only for a cycle the index lacks, so it costs about the window's
chunks: reading every /cycles marker decompressed nearly every chunk of the file (a 1 s window 0.01 -> 0.74 s)."""

from __future__ import annotations

import shutil

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from record_synth import DT_NS, JOINTS, context, tick

from cellguard.record.reader import NO_CYCLE, Record, _placed, open_record
from cellguard.record.writer import RecordConfig, Recorder

CONFIG = RecordConfig(decimated_hz=1000, index_part_rows=7)  # every tick decimated; the index in several parts
MS = 1_000_000


def make(folder, plan) -> list:
    """A record of ``plan``: ("begin", cycle, k), ("end", cycle, k) at tick k, ("ticks", cycle, k0, k1) stamped
    ``cycle``; the folder with its index, and a copy of the record alone (read from its markers)."""
    rec = Recorder.create(folder, joints=JOINTS, dt_ns=DT_NS, context=context(record=CONFIG.to_dict()),
                          config=CONFIG, epoch_wall_ns=1_790_000_000_000_000_000)
    for step, cycle, *k in plan:
        if step == "begin":
            rec.cycle_begin(cycle, "acceptance", k[0] * DT_NS)
        elif step == "end":
            rec.cycle_end({"cycle": cycle, "phase": "acceptance", "success": True, "features": {}}, k[0] * DT_NS)
        else:
            for i in range(*k):
                tick(rec, i, cycle)
    rec.close()
    bare = folder.with_name(folder.name + "-bare")
    bare.mkdir()
    shutil.copy(folder / "record.mcap", bare / "record.mcap")
    return [folder, bare]


def agree(rec) -> None:
    """Each marked cycle's own ticks are those a whole read places in it, and lie in its span."""
    whole = rec.ticks()
    for cycle, (start, end) in rec.cycle_spans().items():
        own = rec.ticks(cycle=cycle)
        assert np.array_equal(own.t_ns, whole.t_ns[whole.cycle == cycle]), cycle
        assert (own.t_ns >= start).all() and (end is None or (own.t_ns <= end).all()), cycle


def test_a_cycle_marked_twice_reads_as_its_last_marking_everywhere(tmp_path):
    plan = [("begin", 1, 0), ("ticks", 1, 0, 100), ("end", 1, 100),
            ("begin", 1, 200), ("ticks", 1, 200, 300), ("end", 1, 300)]
    for folder in make(tmp_path / "twice", plan):
        with open_record(folder) as rec:
            assert rec.cycle_spans() == {1: (200 * MS, 300 * MS)}, folder
            agree(rec)
            assert np.array_equal(rec.ticks(cycle=1).t_ns, np.arange(200, 300) * MS), folder
            whole = rec.ticks()
            assert (whole.cycle[whole.t_ns < 200 * MS] == NO_CYCLE).all(), folder


def test_a_window_reads_the_index_not_every_marker(tmp_path, monkeypatch):
    """40 cycles of 100 ms (a chunk each) with 20 ms between, then a last cycle the run was killed in (no index
    row: its span comes from the markers)."""
    plan = []
    for c in range(40):
        plan += [("begin", c, 120 * c), ("ticks", c, 120 * c, 120 * c + 120), ("end", c, 120 * c + 100)]
    plan += [("begin", 40, 4800), ("ticks", 40, 4800, 4900)]
    indexed, bare = make(tmp_path / "run", plan)
    read, chunk_messages = [], Record._chunk_messages  # the chunks a read decompresses, counted

    def counted(self, ref, *rest):
        read.append(ref)
        return chunk_messages(self, ref, *rest)

    monkeypatch.setattr(Record, "_chunk_messages", counted)
    for folder in (indexed, bare):
        with open_record(folder) as rec:
            whole, chunks = rec.ticks(), len(rec.layout.chunks)
        assert chunks > 40
        for start, end in ((2050, 2150), (4850, 4899)):
            with open_record(folder) as rec:
                read.clear()
                window = rec.ticks(start_ns=start * MS, end_ns=end * MS)
                cost = len(read)
                agree(rec)
            inside = (whole.t_ns >= start * MS) & (whole.t_ns <= end * MS)
            assert np.array_equal(window.cycle, whole.cycle[inside]), (folder, start)
            assert set(window.cycle.tolist()) == ({17, NO_CYCLE} if start == 2050 else {40})
            if folder == indexed and start == 2050:
                assert cost <= 5, cost  # the context's chunk, the window's and the one before it
            elif folder == bare:
                assert cost > chunks / 2, cost  # no index: every marker is read


TIMES = st.integers(-8, 8)  # few, so that ticks fall on the spans' bounds


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(TIMES, st.integers(0, 8)), max_size=60),
       st.dictionaries(st.integers(0, 6), st.tuples(TIMES, st.none() | TIMES)))
def test_placed_is_the_stamp_where_the_tick_lies_in_its_span(ticks, spans):
    t = np.array([tt for tt, _ in ticks], np.int64)
    stamps = np.array([s for _, s in ticks], np.int32)
    expected = [s if s not in spans or (spans[s][0] <= tt and (spans[s][1] is None or tt <= spans[s][1]))
                else NO_CYCLE for tt, s in ticks]
    placed = _placed(t, stamps, spans.get)
    assert placed.dtype == np.int64 and placed.tolist() == expected


def _rewrite_index(folder, edit) -> None:
    """Each part of ``folder``'s cycle index rewritten as ``edit(table)`` returns it."""
    import pyarrow.parquet as pq

    for part in (folder / "index" / "cycles").glob("day=*/*.parquet"):
        pq.write_table(edit(pq.read_table(part)), part)


def test_an_index_part_that_names_no_run_or_holds_bad_rows_is_left_to_the_markers(tmp_path):
    """An unnamed part beside a record with an id (an older run's, left by a killed ``--overwrite``) put cycles the
    record never had in every read; a part's rows are checked as markers are (an end before its start, a null end)."""
    import pyarrow as pa

    plan = [("begin", 0, 0), ("ticks", 0, 0, 100), ("end", 0, 100), ("begin", 1, 120), ("ticks", 1, 120, 220),
            ("end", 1, 220)]

    def foreign(table):  # another run's spans: every cycle 10 ms long, five of them, no run named
        n = 5
        return pa.table({"cycle": pa.array(range(n), pa.int64()), "t_start_ns": pa.array([0] * n, pa.int64()),
                         "t_end_ns": pa.array([10 * MS] * n, pa.int64())})

    def reversed_or_open(table):  # the record's own id kept: ends before starts, or null
        ends = [None if i % 2 else start - 1 for i, start in enumerate(table["t_start_ns"].to_pylist())]
        return table.set_column(table.schema.get_field_index("t_end_ns"), "t_end_ns", pa.array(ends, pa.int64()))

    for edit in (foreign, reversed_or_open):
        folder = make(tmp_path / edit.__name__, plan)[0]
        with open_record(folder) as rec:
            marked = rec.cycle_spans()
        _rewrite_index(folder, edit)
        with open_record(folder) as rec:
            assert rec.cycle_spans() == marked, edit.__name__
            agree(rec)
