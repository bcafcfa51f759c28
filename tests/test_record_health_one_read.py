"""``Record.health()`` reads the file once, in file order: it read it six times (every message for the sequence
numbers, then /cycles, /events, /measurements, /chunks and the ticks each in a pass of its own, every chunk
decompressed again), and a 178 MB record's health took 14.2 s of a 14.8 s ``cellguard diagnose``. What it notes as
malformed is what the readers skip: the same ``Health`` whether they read the record first or not."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from record_synth import DT_NS, JOINTS, context, rewrite, tick

from cellguard.control.events import Event
from cellguard.policy.chunk import ActionChunk
from cellguard.record import reader as reader_module
from cellguard.record.reader import open_record
from cellguard.record.schemas import TICKS
from cellguard.record.writer import RecordConfig, Recorder


@pytest.fixture(scope="module")
def original(tmp_path_factory) -> Path:
    """Four cycles of 1000 ticks with a chunk and a camera reading every 100 ticks, an event at tick 1500 (a
    full-rate window from the start: the pre-trigger window is 10 s)."""
    folder = tmp_path_factory.mktemp("orig")
    rec = Recorder.create(folder, joints=JOINTS, dt_ns=DT_NS, context=context(record=RecordConfig().to_dict()),
                          epoch_wall_ns=1_790_000_000_000_000_000)
    k = 0
    for c in range(4):
        rec.cycle_begin(c, "acceptance" if c < 2 else "production", k * DT_NS)
        for _ in range(1000):
            tick(rec, k, c)
            if k % 100 == 0:
                rec.measurements(k * DT_NS, c, {"part": [0.1, 0.2, float(k)], "fixture": [0.3]})
                rec.chunk(ActionChunk(np.full((10, len(JOINTS)), k / 1e3), k * DT_NS, 10 * DT_NS), k * DT_NS, 1000)
            if k == 1500:
                rec.event(Event(k * DT_NS, "position_clamp", "test", joint="elbow", asked=1.0, sent=0.5), c)
            k += 1
        rec.cycle_end({"cycle": c, "phase": "production", "success": True, "features": {"x": float(c)}}, k * DT_NS)
    rec.close()
    return folder


def _healths(folder: Path):
    """The record's health read first, and read after every reader has read it through."""
    with open_record(folder) as rec:
        fresh = rec.health()
    with open_record(folder) as rec:
        list(rec.cycles()), list(rec.events()), list(rec.measurements()), list(rec.chunks()), rec.ticks()
        return fresh, rec.health()


def _other_joints(data: bytes) -> bytes:
    batch = TICKS.decode(data)
    return TICKS.encode({**batch, "joints": ["a"] * len(batch["joints"])})


def test_health_decompresses_each_chunk_once(original, monkeypatch):
    reads = []
    read_chunk = reader_module.read_chunk
    monkeypatch.setattr(reader_module, "read_chunk", lambda buf, ref, *a: reads.append(ref.offset)
                        or read_chunk(buf, ref, *a))
    with open_record(original) as rec:
        rec.contexts  # noqa: B018 - the context is read on opening a record's contents, before health
        reads.clear()
        health = rec.health()
    assert reads == [ref.offset for ref in rec.layout.chunks]
    assert health.ok and health.messages["/ticks/full"] > 0 and health.messages["/measurements"] == 40, health
    assert _healths(original) == (health, health)


def test_health_notes_what_the_readers_skip(original, tmp_path):
    """A malformed message of every topic read, a reading of other names and tick batches of other joints."""
    seen: dict[str, int] = {}

    def edit(topic: str, payload: dict) -> dict:
        n = seen[topic] = seen.get(topic, 0) + 1
        if topic == "/cycles" and n in (2, 4):
            payload["cycle"] = "two" if n == 2 else -1
        if topic == "/events":
            payload["t_ns"] = "soon"
        if topic == "/measurements" and n in (3, 5):
            payload["measurements"] = "none" if n == 3 else {"part": [1.0]}
        return payload

    def edit_bytes(topic: str, data: bytes) -> bytes:
        n = seen[topic + " bytes"] = seen.get(topic + " bytes", 0) + 1
        if topic == "/chunks" and n == 7 or topic.startswith("/ticks/") and n == 3:
            return data[:-3]
        return _other_joints(data) if topic.startswith("/ticks/") and n == 5 else data

    rewrite(original, tmp_path, edit=edit, edit_bytes=edit_bytes)
    fresh, after = _healths(tmp_path)
    assert fresh == after
    assert fresh.off_schema == {"/cycles": 2, "/events": 1, "/measurements": 2, "/chunks": 1, "/ticks/decimated": 2,
                                "/ticks/full": 2}, fresh


@pytest.mark.parametrize("junk, other, noted", [
    (30, 1, {"/ticks/decimated": 30, "/ticks/full": 1}),  # full-rate batches before the first decimated one
    (None, 2, {"/ticks/full": 1}),  # no decimated batch: the first full-rate one names the joints
])
def test_the_first_decimated_batch_names_the_joints_wherever_it_lies(original, tmp_path, junk, other, noted):
    """``ticks()`` takes the joints of the first decimated batch read, else the first full-rate one's; read in file
    order, a full-rate batch may come before the first decimated batch that decodes."""
    seen: dict[str, int] = {}

    def edit_bytes(topic: str, data: bytes) -> bytes:
        n = seen[topic] = seen.get(topic, 0) + 1
        if topic == "/ticks/decimated" and (junk is None or n <= junk):
            return b"junk"
        return _other_joints(data) if topic == "/ticks/full" and n == other else data

    rewrite(original, tmp_path, edit_bytes=edit_bytes)
    fresh, after = _healths(tmp_path)
    assert fresh == after
    if junk is None:
        noted = {"/ticks/decimated": fresh.messages["/ticks/decimated"], **noted}
    assert fresh.off_schema == noted, fresh
