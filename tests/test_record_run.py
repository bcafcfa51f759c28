"""A real run writes its record: the mcap package opens it, and a full disk stops the cell (category 2)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from record_synth import FullDisk, SlowDisk
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.record.reader import open_record
from cellguard.record.schemas import CHANNELS
from cellguard.record.session import RESERVE_FILE, RunRecording
from cellguard.runtime import Run, run_scenario
from cellguard.scenario import load_scenario

DEMO = Path(__file__).parents[1] / "src" / "cellguard" / "scenarios" / "demo.yaml"


def _short_demo(cycles: int = 3):
    return load_scenario(DEMO).model_copy(update={"acceptance_cycles": 2, "production_cycles": cycles - 2})


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    summary = run_scenario(_short_demo(), out)
    return out, summary


def test_the_mcap_package_lists_every_channel_with_its_schema(run_folder):
    out, _ = run_folder
    with open(out / "record.mcap", "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        counts = summary.statistics.channel_message_counts
        for channel in summary.channels.values():
            schema = summary.schemas[channel.schema_id]
            assert schema.name and schema.encoding in ("jsonschema", "ros2msg")
            assert len(schema.data) >= len("string data")
        topics = {c.topic for c in summary.channels.values()}
        assert topics == {c.topic for c in CHANNELS}
        by_topic = {c.topic: counts.get(c.id, 0) for c in summary.channels.values()}
        for topic in ("/context", "/ticks/decimated", "/chunks", "/cycles", "/measurements"):
            assert by_topic[topic] > 0, topic
        for _, channel, message in reader.iter_messages(topics=["/cycles", "/context", "/measurements"]):
            assert isinstance(json.loads(message.data), dict)


def test_the_record_agrees_with_the_run(run_folder):
    out, summary = run_folder
    with open_record(out, strict=True) as rec:
        cycles = list(rec.cycles())
        events = list(rec.events())
        context = rec.context
        chunks = list(rec.chunks())
        ticks = rec.ticks(cycle=1)
    assert [c.cycle for c in cycles] == [c["cycle"] for c in summary["cycles"]]
    assert [c.success for c in cycles] == [c["success"] for c in summary["cycles"]]
    for got, want in zip(cycles, summary["cycles"]):
        assert got.features["current_peak.elbow"] == pytest.approx(want["features"]["current_peak.elbow"])
    assert len(events) == len(summary["events"])
    assert context["policy"]["sha256"] == summary["context"]["policy_sha256"]
    assert context["embodiment"]["sha256"] == summary["context"]["profile_sha256"]
    assert context["site"] and context["cell_id"] and context["software"]["mcap"]
    assert "faults" not in context["scenario"]  # ground truth stays out of the record
    assert chunks and chunks[0].actions.shape[1] == 6
    assert len(ticks) > 0 and set(ticks.cycle) == {1}


def test_a_full_disk_stops_the_cell_with_a_category_2_event(tmp_path):
    run = Run(_short_demo(4))
    run.recording = RunRecording.start(tmp_path, run, opener=FullDisk(150_000))
    for _ in range(4):
        run.cycle()
        if run.stopped:
            break
    run.recording.close()
    assert run.stopped and "ENOSPC" in run.stopped
    stop = next(e for e in run.events if e.kind == "record_failed")
    assert stop.category == 2
    after = [e.kind for e in run.events if e.t_ns >= stop.t_ns and e is not stop]
    assert after == ["protective_stop"]  # the guard brakes and holds; nothing else happens
    with open_record(tmp_path) as rec:  # what was written before reads back
        health = rec.health()
        ticks = rec.ticks(rate="decimated")
    assert not health.ok and health.chunks_damaged == 0
    assert len(ticks) > 10 and ticks.t_ns[-1] <= stop.t_ns


def test_after_a_full_disk_the_arm_brakes_under_its_limits_holds_and_does_not_retreat(tmp_path):
    """The stop held the measured pose at once (a step from the last command mid-motion) without reading the
    robot meanwhile, and the retreat to home then moved it with nothing recorded."""
    run = Run(_short_demo(4))
    run.recording = RunRecording.start(tmp_path, run, opener=FullDisk(150_000))
    write, sent = run.cell.write, []
    run.cell.write = lambda q: sent.append(np.array(q)) or write(q)
    run.run_cycles()
    run.recording.close()
    kinds = [e.kind for e in run.events]
    assert "record_failed" in kinds and "retreat_begin" not in kinds
    speeds = np.abs(np.diff(np.array(sent), axis=0)) / (run.cell.dt_ns * 1e-9)
    assert (speeds <= run.cell.profile.array("velocity") * 1.001).all()
    assert speeds[-1].max() < 1e-3  # at a standstill at the end


def test_in_simulated_time_a_slow_disk_slows_the_loop_and_loses_no_tick(tmp_path):
    """Nothing waits on a clock in simulation: the loop waits for the writer process instead of dropping."""
    run = Run(_short_demo(1))
    run.recording = RunRecording.start(tmp_path, run, opener=SlowDisk(0.02), queue_s=0.05)
    run.cycle()
    run.recording.close()
    assert run.recording.dropped == 0 and run.recording.high_water <= 50
    assert "record_queue_full" not in [e.kind for e in run.events]
    with open_record(tmp_path) as rec:
        assert rec.health().ok
        t_ns = rec.ticks(rate="decimated").t_ns
    assert len(t_ns) > 100 and set(np.diff(t_ns).tolist()) == {20_000_000}  # every 20th tick, none missing


def _ticks_fed(recording, run, n: int) -> list[int]:
    """Feed ``n`` ticks of the cell's state; the servo-thread cost of each call [ns]."""
    state, costs = run.cell.read(), []
    for k in range(n):
        state = state._replace(t_ns=k * 1_000_000)
        began = time.perf_counter_ns()
        recording.tick(state.t_ns, state.q, state.q, state)
        costs.append(time.perf_counter_ns() - began)
    return costs


def test_on_wall_time_a_stalled_writer_never_blocks_the_servo_thread(tmp_path):
    """The writer process stuck on a disk that takes 50 ms per write: the loop runs on, ticks past the queue
    are dropped and counted with one ``record_queue_full`` event, and the ticks before them read back."""
    run = Run(_short_demo(1), realtime=True)
    recording = RunRecording.start(tmp_path, run, opener=SlowDisk(0.05), queue_s=0.2)  # 200 ticks at 1 kHz
    costs = _ticks_fed(recording, run, 1000)
    recording.close()
    run.close()
    assert max(costs) < 20_000_000  # no 50 ms write reached the loop (its calls take microseconds)
    assert recording.dropped >= 700 and 190 <= recording.high_water < 200
    assert [e.kind for e in run.events].count("record_queue_full") == 1
    with open_record(tmp_path) as rec:
        t_ns = rec.ticks(rate="decimated").t_ns
    assert t_ns[0] == 0 and len(t_ns) >= 10 and t_ns[-1] < 300_000_000


def test_when_the_loops_process_dies_the_writer_finishes_the_file_and_says_so(tmp_path):
    """SIGKILL of the loop's process: the writer process takes every tick already in the ring and closes the
    record properly (summary and all), instead of leaving the open chunk unwritten; a ``run_process_lost``
    event at the last tick says the run did not end, and the disk reserve the loop would free is freed."""
    script = (f"import os, signal, sys; sys.path.insert(0, {str(Path(__file__).parent)!r})\n"
              "from test_record_run import _short_demo, _ticks_fed\n"
              "from cellguard.record.session import RunRecording\n"
              "from cellguard.runtime import Run\n"
              "run = Run(_short_demo(1))\n"
              f"recording = RunRecording.start({str(tmp_path)!r}, run)\n"
              "_ticks_fed(recording, run, 1234)\n"
              "os.kill(os.getpid(), signal.SIGKILL)\n")
    result = subprocess.run([sys.executable, "-c", script], timeout=120)
    assert result.returncode == -signal.SIGKILL
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:  # the orphaned writer notices within POLL_S, writes the end, frees the reserve
        with open_record(tmp_path) as rec:
            if rec.health().finished and not (tmp_path / RESERVE_FILE).exists():
                break
        time.sleep(0.05)
    with open_record(tmp_path) as rec:
        assert rec.health().ok and rec.health().finished
        t_ns = rec.ticks(rate="decimated").t_ns
        events = list(rec.events())
    assert t_ns[-1] == 1220 * 1_000_000  # the last decimated tick before the kill (every 20th of 1234)
    assert [(e.kind, e.t_ns) for e in events] == [("run_process_lost", 1233 * 1_000_000)]
    assert not (tmp_path / RESERVE_FILE).exists()
    info = CliRunner().invoke(app, ["record", "info", str(tmp_path)])
    assert info.exit_code == 0 and "not by the run: the run's process ended without finishing" in info.output


def test_a_writer_process_that_dies_stops_the_cell(tmp_path):
    run = Run(_short_demo(1))
    run.recording = RunRecording.start(tmp_path, run)
    os.kill(run.recording._process.pid, signal.SIGKILL)
    run.cycle()
    run.recording.close()
    run.close()
    assert run.stopped and "the recorder process ended" in run.stopped
    assert [e.category for e in run.events if e.kind == "record_failed"] == [2]


def test_tf_poses_are_mujocos_at_the_recorded_joint_positions(run_folder):
    """Each ``/tf`` message, decoded by the ROS 2 reader, puts every moving link where MuJoCo's kinematics
    puts it relative to its parent at the ``/joint_states`` positions of the same stamp."""
    import mujoco
    from mcap_ros2.decoder import DecoderFactory

    out, _ = run_folder
    model = Run(_short_demo()).cell.model
    data = mujoco.MjData(model)
    states, frames = {}, []
    with open(out / "record.mcap", "rb") as f:
        for _, channel, message, decoded in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
                topics=["/joint_states", "/tf"]):
            if channel.topic == "/joint_states":
                states[message.log_time] = dict(zip(decoded.name, decoded.position))
            else:
                frames.append((message.log_time, decoded.transforms))
    assert len(frames) == len(states) > 100
    prismatic = 0
    for log_time, transforms in frames[::25]:
        for name, value in states[log_time].items():
            joint = model.joint(name)
            data.qpos[joint.qposadr[0]] = value
            prismatic += int(joint.type[0]) == int(mujoco.mjtJoint.mjJNT_SLIDE)
        mujoco.mj_kinematics(model, data)
        for t in transforms:
            parent, child = model.body(t.header.frame_id).id, model.body(t.child_frame_id).id
            rotation = data.xmat[parent].reshape(3, 3)
            want_xyz = rotation.T @ (data.xpos[child] - data.xpos[parent])
            inverse, want_quat = np.zeros(4), np.zeros(4)
            mujoco.mju_negQuat(inverse, data.xquat[parent])
            mujoco.mju_mulQuat(want_quat, inverse, data.xquat[child])
            got = t.transform
            assert [got.translation.x, got.translation.y, got.translation.z] == pytest.approx(want_xyz, abs=1e-9)
            quat = np.array([got.rotation.w, got.rotation.x, got.rotation.y, got.rotation.z])
            assert abs(float(quat @ want_quat)) == pytest.approx(1.0, abs=1e-9)  # the same rotation (q or -q)
    assert prismatic  # the gripper's slide joint is checked too


@pytest.mark.parametrize("realtime", [False, True])
def test_a_recorder_bug_stops_the_cell_and_never_the_loop(tmp_path, monkeypatch, realtime):
    """Any exception inside the recorder (not only a write error) ends the recording and stops the cell with
    category 2 ``record_failed``, on simulated and on wall time (the writer process inherits the bug)."""
    from cellguard.record.writer import Recorder

    calls = {"n": 0}
    flush = Recorder._flush

    def buggy(self, *args):
        calls["n"] += 1
        if calls["n"] == 5:
            raise ValueError("a bug")
        flush(self, *args)

    monkeypatch.setattr(Recorder, "_flush", buggy)
    run = Run(_short_demo(1), realtime=realtime)
    run.recording = RunRecording.start(tmp_path, run)
    run.cycle()
    run.recording.close()
    run.close()
    assert run.stopped and "recorder fault (ValueError: a bug)" in run.stopped
    stop = next(e for e in run.events if e.kind == "record_failed")
    assert stop.category == 2
    with open_record(tmp_path) as rec:  # what was written before the bug reads back
        assert len(rec.ticks(rate="decimated")) > 0
