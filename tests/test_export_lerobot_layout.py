"""``cellguard record to-lerobot`` without lerobot installed: frames, values and metadata as written."""

from __future__ import annotations

import json

import numpy as np
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.record.reader import open_record
from cellguard.runtime import run_scenario
from cellguard.scenario import parse_scenario

runner = CliRunner()


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A real run: one good cycle, then a tool slip fails the next two (full-rate windows around them)."""
    out = tmp_path_factory.mktemp("run")
    run_scenario(parse_scenario({"cell": "arm-pick-place", "seed": 2, "policy": "scripted", "acceptance_cycles": 2,
                                 "production_cycles": 1, "faults": [{"kind": "tool_slip", "at_cycle": 1}]}), out)
    return out


def _export(folder, out, *args):
    result = runner.invoke(app, ["record", "to-lerobot", str(folder), "-o", str(out), *args])
    assert result.exit_code == 0, result.output
    return json.loads((out / "meta/info.json").read_text()), pq.read_table(out / "data/chunk-000/file-000.parquet")


def test_frames_are_the_decimated_ticks_of_each_cycle(folder, tmp_path):
    info, data = _export(folder, tmp_path / "ds")
    with open_record(folder) as rec:
        ticks = [rec.ticks(cycle=c, rate="decimated") for c in range(3)]
        full = rec.ticks(cycle=1, rate="all")
        shown = [json.loads(m.data) for m in rec.messages(["/measurements"])]
    assert len(full) > len(ticks[1])  # the failed cycle kept full rate too; only the 50 Hz stream is exported
    assert info["codebase_version"] == "v3.0" and info["fps"] == 50 and info["total_episodes"] == 3
    assert info["total_frames"] == data.num_rows == sum(len(t) for t in ticks)
    assert info["features"]["action"]["names"] == list(ticks[0].joints)
    episode = np.array(data["episode_index"])
    for i, t in enumerate(ticks):
        rows = episode == i
        np.testing.assert_array_equal(np.array(data["action"].to_pylist())[rows], t.q_cmd.astype(np.float32))
        state = np.array(data["observation.state"].to_pylist())[rows]
        np.testing.assert_array_equal(state, t.q_meas.astype(np.float32))
        np.testing.assert_allclose(np.array(data["timestamp"])[rows], np.arange(len(t)) / 50, atol=1e-6)
    assert np.array_equal(np.array(data["index"]), np.arange(data.num_rows))
    # the camera reading a frame carries is the latest one the policy was shown, in its cycle
    frame_t = ticks[0].t_ns[40]
    latest = max((m for m in shown if m["cycle"] == 0 and m["t_ns"] <= frame_t), key=lambda m: m["t_ns"])
    np.testing.assert_allclose(data["observation.environment_state"][40].as_py()[:3],
                               latest["measurements"]["part_in_camera"], atol=1e-6)


def test_episodes_tasks_and_stats(folder, tmp_path):
    _export(folder, tmp_path / "ds", "--task", "pick the part, place it in the bin")
    episodes = pq.read_table(tmp_path / "ds/meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert [e["cellguard/success"] for e in episodes] == [True, False, False]
    assert [e["dataset_to_index"] - e["dataset_from_index"] for e in episodes] == [e["length"] for e in episodes]
    assert episodes[1]["dataset_from_index"] == episodes[0]["dataset_to_index"]
    assert episodes[0]["tasks"] == ["pick the part, place it in the bin"]
    tasks = pq.read_table(tmp_path / "ds/meta/tasks.parquet")
    assert tasks["__index_level_0__"].to_pylist() == ["pick the part, place it in the bin"]
    stats = json.loads((tmp_path / "ds/meta/stats.json").read_text())
    data = pq.read_table(tmp_path / "ds/data/chunk-000/file-000.parquet")
    action = np.array(data["action"].to_pylist(), dtype=np.float64)
    np.testing.assert_allclose(stats["action"]["mean"], action.mean(0), rtol=1e-9)
    assert stats["action"]["count"] == [len(action)] and len(stats["action"]["q99"]) == action.shape[1]


def test_success_only_and_a_lower_fps(folder, tmp_path):
    info, _ = _export(folder, tmp_path / "ok", "--success-only")
    with open_record(folder) as rec:
        good = rec.ticks(cycle=0, rate="decimated")
    assert info["total_episodes"] == 1 and info["total_frames"] == len(good)
    info, data = _export(folder, tmp_path / "slow", "--fps", "25", "--success-only")
    assert info["fps"] == 25 and info["total_frames"] == len(good.t_ns[::2])
    np.testing.assert_array_equal(np.array(data["action"].to_pylist()), good.q_cmd[::2].astype(np.float32))


@pytest.mark.parametrize("args, names", [(["--fps", "30"], "--fps"), (["--fps", "0"], "--fps")])
def test_bad_fps_is_one_line_and_exit_2(folder, tmp_path, args, names):
    result = runner.invoke(app, ["record", "to-lerobot", str(folder), "-o", str(tmp_path / "ds"), *args])
    assert result.exit_code == 2 and names in result.output and "Traceback" not in result.output
    assert not (tmp_path / "ds").exists()


@pytest.mark.parametrize("task", ["pick\nplace", "pick\x1b[2Jplace", "pick\x00"])
def test_a_task_with_control_characters_is_one_line_and_exit_2(folder, tmp_path, task):
    result = runner.invoke(app, ["record", "to-lerobot", str(folder), "-o", str(tmp_path / "ds"), "--task", task])
    assert result.exit_code == 2 and result.output.startswith("error: --task: ")
    assert "control characters" in result.output
    assert len(result.output.splitlines()) == 1 and "\x1b" not in result.output and not (tmp_path / "ds").exists()


def test_refuses_a_folder_that_is_not_empty(folder, tmp_path):
    (tmp_path / "ds").mkdir()
    (tmp_path / "ds" / "keep.txt").write_text("mine")
    result = runner.invoke(app, ["record", "to-lerobot", str(folder), "-o", str(tmp_path / "ds")])
    assert result.exit_code == 2 and "not empty" in result.output
    assert (tmp_path / "ds" / "keep.txt").read_text() == "mine"


def test_frames_a_nanosecond_off_the_period_are_no_gap_and_a_missing_frame_is():
    """The demo's clock stepped 20,000,001 ns once in a cycle: 3 of its 80 cycles were dropped as gaps."""
    from cellguard.record.lerobot_export import evenly_spaced

    t = np.arange(10) * 20_000_000
    assert evenly_spaced(t, 50) and evenly_spaced(t + np.array([0, 1, 0, -1, 0, 0, 1, 1, 0, 0]), 50)
    assert not evenly_spaced(np.delete(t, 4), 50) and not evenly_spaced(t, 25)
