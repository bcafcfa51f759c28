"""Synthetic recordings for the record tests: every value is a known function of the tick index.

Run as a script it records ticks until killed, writing the last completed tick index to a
progress file after every tick (the SIGKILL test reads it after the kill).
"""

from __future__ import annotations

import errno
import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from cellguard.control.events import Event
from cellguard.record.writer import RecordConfig, Recorder
from cellguard.robot.state import State

JOINTS = ("shoulder_pan", "shoulder_lift", "elbow", "wrist_flex", "wrist_roll", "gripper")
DT_NS = 1_000_000


def values(k: int) -> dict[str, np.ndarray]:
    """The six tick fields of tick ``k`` (exactly representable in float32)."""
    base = (k % 4096) / 64.0 + np.arange(len(JOINTS))
    return {"q_ref": base, "q_cmd": base + 0.5, "q_meas": base + 0.25, "qd_meas": -base,
            "effort": base * 2.0, "current": base / 4.0}


def tick(rec: Recorder, k: int, cycle: int) -> None:
    v = values(k)
    rec.tick(cycle, v["q_ref"], v["q_cmd"], State(k * DT_NS, v["q_meas"], v["qd_meas"], v["effort"], v["current"]))


def context(**extra) -> dict:
    return {"site": "test-site", "cell_id": "cell-7", "servo_period_ns": DT_NS, "policy": {"source": "scripted",
            "sha256": "ab" * 32}, "fixture_datum": [0.3, 0.1, 0.0], **extra}


def record(folder: Path, cycles: int, ticks_per_cycle: int, events: dict[int, str] | None = None,
           config: RecordConfig = RecordConfig(), opener=None, failed: set[int] = frozenset()) -> Recorder:
    """Write ``cycles`` cycles; ``events`` maps a tick index to an event kind; ``failed`` cycles fail."""
    kwargs = {} if opener is None else {"opener": opener}
    rec = Recorder.create(folder, joints=JOINTS, dt_ns=DT_NS, context=context(record=config.to_dict()),
                          config=config, epoch_wall_ns=1_790_000_000_000_000_000, **kwargs)
    k = 0
    for c in range(cycles):
        phase = "acceptance" if c < cycles // 2 else "production"
        rec.cycle_begin(c, phase, k * DT_NS)
        for _ in range(ticks_per_cycle):
            tick(rec, k, c)
            if events and k in events:
                rec.event(Event(k * DT_NS, events[k], "test", joint="elbow", asked=1.0, sent=0.5), c)
            k += 1
        rec.cycle_end({"cycle": c, "phase": phase, "success": c not in failed,
                       "features": {"current_peak.elbow": float(c), "cycle": float(c)}}, k * DT_NS)
    rec.close()
    return rec


def rewrite(source: Path, target: Path, metadata: dict[str, dict[str, str]] | None = None,
            edit: Callable[[str, dict], dict] | None = None, sequence: int | None = None,
            edit_bytes: Callable[[str, bytes], bytes] | None = None, chunk_size: int = 1 << 20) -> None:
    """Copy the record of folder ``source`` into folder ``target`` (without its index) through the mcap Writer, as
    a tampered or foreign file: ``metadata`` updates the metadata records it names, ``edit(topic, payload)``
    returns each JSON message's payload, ``edit_bytes(topic, data)`` each message's bytes (a binary one's),
    ``sequence`` numbers every message alike; chunks of about ``chunk_size`` bytes (the mcap Writer's default)."""
    target.mkdir(parents=True, exist_ok=True)
    with open(source / "record.mcap", "rb") as f, open(target / "record.mcap", "wb") as out:
        reader = make_reader(f)
        summary = reader.get_summary()
        writer = Writer(out, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        writer.start(profile="cellguard", library="test")
        for record in reader.iter_metadata():
            writer.add_metadata(record.name, {**record.metadata, **(metadata or {}).get(record.name, {})})
        for schema_id, schema in summary.schemas.items():
            assert writer.register_schema(schema.name, schema.encoding, schema.data) == schema_id
        for channel_id, channel in sorted(summary.channels.items()):
            assert writer.register_channel(channel.topic, channel.message_encoding, channel.schema_id,
                                           channel.metadata) == channel_id
        for _, channel, m in reader.iter_messages(log_time_order=False):
            data = m.data
            if edit is not None and channel.message_encoding == "json":
                data = json.dumps(edit(channel.topic, json.loads(data))).encode()
            if edit_bytes is not None:
                data = edit_bytes(channel.topic, data)
            writer.add_message(m.channel_id, m.log_time, data, m.publish_time,
                               m.sequence if sequence is None else sequence)
        writer.finish()


class FullRateAltered:
    """An ``edit_bytes`` for ``rewrite`` that shows which copy of a tick a reader keeps (the recorder writes the same
    values to both streams): each full-rate batch's q_ref raised by 1000 times its number, batch ``overlap_at``
    moved half a batch back over the one before, on the servo grid (``overlap``: the times it moved over), batch
    ``other_joints_at`` naming other joints."""

    def __init__(self, overlap_at: int = 5, other_joints_at: int | None = None):
        self.overlap_at, self.other_joints_at = overlap_at, other_joints_at
        self.n, self.overlap = 0, None

    def __call__(self, topic: str, data: bytes) -> bytes:
        from cellguard.record.schemas import TICKS

        if topic != "/ticks/full":
            return data
        d = TICKS.decode(data)
        self.n += 1
        d = {**d, "q_ref": d["q_ref"] + 1000.0 * self.n}
        if self.n == self.overlap_at:
            t = d["t_ns"]
            d["t_ns"] = t - (len(t) // 2) * (t[1] - t[0])
            self.overlap = d["t_ns"][:len(t) // 2]
        if self.n == self.other_joints_at:
            d["joints"] = [*d["joints"][:-1], "other"]
        return TICKS.encode(d)


class _File:
    """A real file behind a test's own ``write``."""

    def __init__(self, f):
        self.f = f

    def __getattr__(self, name):
        return getattr(self.f, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.f.close()


class SlowDisk:
    """Files whose every write takes ``seconds`` (a worn SD card, a network share)."""

    def __init__(self, seconds: float):
        self.seconds = seconds

    def __call__(self, path: Path):
        return _SlowFile(open(path, "wb"), self.seconds)


class _SlowFile(_File):
    def __init__(self, f, seconds: float):
        super().__init__(f)
        self.seconds = seconds

    def write(self, data) -> int:
        time.sleep(self.seconds)
        return self.f.write(data)


class FullDisk:
    """A file that accepts ``capacity`` bytes, shared by every file of a folder, then raises ENOSPC."""

    def __init__(self, capacity: int):
        self.left = capacity

    def __call__(self, path: Path):
        return _FullDiskFile(open(path, "wb"), self)


class _FullDiskFile(_File):
    def __init__(self, f, disk: FullDisk):
        super().__init__(f)
        self.disk = disk

    def write(self, data) -> int:
        data = bytes(data)
        if len(data) > self.disk.left:
            self.f.write(data[:self.disk.left])  # a real full disk takes what fits
            self.disk.left = 0
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self.disk.left -= len(data)
        return self.f.write(data)


def _run_until_killed(folder: Path, progress: Path) -> None:
    config = RecordConfig(decimated_hz=1000.0, pre_trigger_s=0.0, post_trigger_s=0.0)
    rec = Recorder.create(folder, joints=JOINTS, dt_ns=DT_NS, context=context(record=config.to_dict()), config=config)
    fd = os.open(progress, os.O_WRONLY | os.O_CREAT)
    k = 0
    while True:
        tick(rec, k, k // 1000)
        os.pwrite(fd, k.to_bytes(8, "little"), 0)
        k += 1
        if k % 20 == 0:
            time.sleep(0.001)


if __name__ == "__main__":
    _run_until_killed(Path(sys.argv[1]), Path(sys.argv[2]))


def away_from_home_run(folder: Path, acceptance_cycles: int, production_cycles: int) -> Path:
    """A real run (1 s time cycles) whose replayed policy leaves the arm away from home, so its retreat begins at the
    last cycle's very end: ``folder``/run."""
    from cellguard.robot.registry import make_cell
    from cellguard.runtime import run_scenario
    from cellguard.scenario import parse_scenario

    home = np.array(make_cell("arm-pick-place").read().q, dtype=np.float64)
    t = np.arange(0.0, 3.0, 0.1)
    actions = np.array([[home + np.array([0.5 * (s + k * 0.02), 0, 0, 0, 0, 0]) for k in range(1, 26)] for s in t])
    np.savez(folder / "turn.npz", t=t, actions=actions, dt=np.float64(0.02))
    run_scenario(parse_scenario({"cell": "arm-pick-place", "policy": f"replay:{folder / 'turn.npz'}",
                                 "acceptance_cycles": acceptance_cycles, "production_cycles": production_cycles,
                                 "cycle": {"source": "time", "seconds": 1.0}}), folder / "run")
    return folder / "run"
