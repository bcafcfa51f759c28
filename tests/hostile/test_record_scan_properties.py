"""The record scan parser on arbitrary bytes: it answers or raises RecordError, nothing else.

Inputs are a real record's bytes cut, overwritten, spliced and shuffled by hypothesis, plus raw
random bytes; every readable layout must then also read through ``open_record`` and ``health()``.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cellguard.control.events import Event
from cellguard.errors import CellguardError
from cellguard.record.reader import open_record
from cellguard.record.scan import MAGIC, scan
from cellguard.record.writer import RecordConfig, Recorder
from cellguard.robot.state import State

JOINTS = ("a", "b")


def _record() -> bytes:
    with tempfile.TemporaryDirectory() as tmp:
        rec = Recorder.create(Path(tmp), joints=JOINTS, dt_ns=1_000_000, context={"site": "s", "cell_id": "c"},
                              config=RecordConfig(chunk_ns=20_000_000, fsync_ns=20_000_000, pre_trigger_s=0.05,
                                                  post_trigger_s=0.02))
        z = np.zeros(2)
        for k in range(200):
            rec.tick(0, z, z, State(k * 1_000_000, z + k, z, z, z))
            if k == 120:
                rec.event(Event(k * 1_000_000, "position_clamp", "test", joint="a", asked=1.0, sent=0.5), 0)
        rec.close()
        return (Path(tmp) / "record.mcap").read_bytes()


GOOD = _record()


@st.composite
def damaged(draw) -> bytes:
    data = bytearray(GOOD)
    for _ in range(draw(st.integers(0, 4))):
        kind = draw(st.sampled_from(["overwrite", "cut", "splice", "insert"]))
        at = draw(st.integers(0, max(0, len(data) - 1)))
        if kind == "overwrite":
            patch = draw(st.binary(min_size=1, max_size=64))
            data[at:at + len(patch)] = patch
        elif kind == "cut":
            del data[at:]
        elif kind == "splice":
            end = draw(st.integers(at, len(data)))
            del data[at:end]
        else:
            data[at:at] = draw(st.binary(min_size=1, max_size=64))
    return bytes(data)


def _check(data: bytes) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "record.mcap"
        path.write_bytes(data)
        try:
            scan(path)
            with open_record(path) as rec:
                rec.health()
                list(rec.cycles())
                list(rec.events())
                rec.ticks(rate="all")
        except CellguardError:
            pass


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(damaged())
def test_a_damaged_record_never_raises_anything_but_a_cellguard_error(data):
    _check(data)


@settings(max_examples=100, deadline=None)
@given(st.binary(max_size=2048), st.booleans())
def test_random_bytes_never_raise_anything_but_a_cellguard_error(data, magic):
    _check((MAGIC if magic else b"") + data)
