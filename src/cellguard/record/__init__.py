"""The fault record: writer, reader, context manifest, per-cycle index for long histories.

    writer.Recorder      ticks, chunks, events, cycles and context into record.mcap (+ index/)
    session.RunRecording the recorder as the runner feeds it (never raises into the tick loop)
    reader.open_record   cycles, events, ticks, chunks, context and health of a record
    recovery.recover     a finished copy of a truncated or damaged record
    index                the day-partitioned Parquet index and its DuckDB views
"""

from cellguard.record.reader import CycleRecord, EventRecord, Health, Record, Ticks, open_record
from cellguard.record.recovery import recover
from cellguard.record.writer import RecordConfig, Recorder

__all__ = ["CycleRecord", "EventRecord", "Health", "Record", "RecordConfig", "Recorder", "Ticks", "open_record",
           "recover"]
