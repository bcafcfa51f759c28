"""The evidence of a stage: its runs' records, read once through the record reader.

A run folder holds ``record.mcap`` (read with ``cellguard.record.reader``) and, for a pilot run in
shadow mode, ``shadow.json`` (per chunk: distance to the incumbent, would-clamp, would-stop).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from cellguard.record.reader import CycleRecord, EventRecord, RecordedChunk, Ticks, open_record
from cellguard.record.writer import RECORD_FILE
from cellguard.release.bundle import sha256_file

SHADOW_FILE = "shadow.json"


@dataclass(frozen=True)
class RunEvidence:
    """One run as the gates see it; ``record_id`` names it in the log and on the release page."""

    record_id: str
    name: str
    folder: str
    context: dict
    cycles: tuple[CycleRecord, ...]
    events: tuple[EventRecord, ...]
    chunks: tuple[RecordedChunk, ...]
    ticks: Ticks
    shadow: tuple[dict, ...] | None  # per candidate chunk, or None when the run had no shadow

    def label(self, cycle: int | None = None) -> str:
        return f"record {self.record_id} ({self.name})" + (f" cycle {cycle}" if cycle is not None else "")


def record_id(folder: Path) -> str:
    """A record's id: the first 16 hex characters of its file's sha256 (content-addressed)."""
    return sha256_file(Path(folder) / RECORD_FILE, "record")[:16]


def load_run(folder: Path, name: str, rid: str | None = None) -> RunEvidence:
    folder = Path(folder)
    with open_record(folder) as rec:
        context = rec.context
        cycles, events, chunks = tuple(rec.cycles()), tuple(rec.events()), tuple(rec.chunks())
        ticks = rec.ticks(rate="decimated")
    shadow_path = folder / SHADOW_FILE
    shadow = tuple(json.loads(shadow_path.read_text())["chunks"]) if shadow_path.is_file() else None
    return RunEvidence(rid or record_id(folder), name, str(folder), context, cycles, events, chunks, ticks, shadow)
