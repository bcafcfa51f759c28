"""Crash safety: SIGKILL mid-run, a full disk, a folder that refuses writes."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from record_synth import DT_NS, JOINTS, FullDisk, context, record, values

from cellguard.errors import RecordError
from cellguard.record.reader import open_record
from cellguard.record.writer import RecordConfig, Recorder

SYNTH = Path(__file__).with_name("record_synth.py")


def test_sigkill_loses_at_most_the_open_chunk(tmp_path):
    progress = tmp_path / "progress"
    progress.write_bytes(b"\0" * 8)
    child = subprocess.Popen([sys.executable, str(SYNTH), str(tmp_path / "rec"), str(progress)],
                             cwd=SYNTH.parent, env={**os.environ, "PYTHONPATH": str(SYNTH.parent)})
    try:
        deadline = time.monotonic() + 60
        while int.from_bytes(progress.read_bytes(), "little") < 1500 and time.monotonic() < deadline:
            time.sleep(0.02)
        time.sleep(random.Random(os.getpid()).uniform(0.0, 0.3))
        child.send_signal(signal.SIGKILL)
        assert child.wait(timeout=30) == -signal.SIGKILL
    finally:
        child.kill()
    last = int.from_bytes(progress.read_bytes(), "little")  # last tick the child completed
    assert last >= 1500
    with open_record(tmp_path / "rec") as rec:
        ticks = rec.ticks(rate="decimated")
        health = rec.health()
    k = ticks.t_ns // DT_NS
    np.testing.assert_array_equal(k, np.arange(len(k)))  # every tick from the start, none missing
    np.testing.assert_array_equal(ticks.q_meas, np.stack([values(i)["q_meas"] for i in k]))
    lost_ns = (last - k[-1]) * DT_NS
    # bounded by the flush interval; -1 tick: the kill came between recording a tick and writing its progress
    assert -DT_NS <= lost_ns <= RecordConfig().chunk_ns
    assert not health.finished and not health.ok


def test_full_disk_raises_and_the_earlier_record_reads_back_whole(tmp_path):
    disk = FullDisk(60_000)
    with pytest.raises(RecordError, match="ENOSPC"):
        record(tmp_path, 20, 1000, opener=disk)
    with open_record(tmp_path) as rec:
        ticks = rec.ticks(rate="decimated")
        cycles = list(rec.cycles())
        health = rec.health()
    k = ticks.t_ns // DT_NS
    assert len(k) > 100
    np.testing.assert_array_equal(k, np.arange(0, 20 * len(k), 20))
    np.testing.assert_array_equal(ticks.current, np.stack([values(i)["current"] for i in k]))
    assert [c.cycle for c in cycles] == list(range(len(cycles)))
    assert not health.ok and health.chunks_damaged == 0


def test_after_a_write_error_the_recorder_refuses_everything(tmp_path):
    rec = Recorder.create(tmp_path, joints=JOINTS, dt_ns=DT_NS, context=context(), opener=FullDisk(5_000))
    z = np.zeros(6)
    from cellguard.robot.state import State
    with pytest.raises(RecordError, match="cannot write"):
        for k in range(5000):
            rec.tick(0, z, z, State(k * DT_NS, z, z, z, z))
    assert rec.failed is not None
    with pytest.raises(RecordError, match="stopped earlier"):
        rec.tick(0, z, z, State(10**10, z, z, z, z))
    rec.close()


def test_a_folder_that_refuses_writes_stops_before_anything_runs(tmp_path):
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("")
    with pytest.raises(RecordError, match="cannot start the record"):
        Recorder.create(blocker / "run", joints=JOINTS, dt_ns=DT_NS, context=context())
