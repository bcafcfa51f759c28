"""The exported dataset loads with lerobot's own ``LeRobotDataset``, offline, frame for frame.

Needs the ``lerobot`` extra (torch); skipped where it is not installed.
"""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("HF_HUB_OFFLINE", "1")  # a load that would reach for the hub fails instead of downloading
lerobot_dataset = pytest.importorskip("lerobot.datasets.lerobot_dataset")

import json  # noqa: E402

import numpy as np  # noqa: E402
import pyarrow.parquet as pq  # noqa: E402

from cellguard.record.lerobot_export import export_lerobot  # noqa: E402
from cellguard.record.reader import open_record  # noqa: E402
from cellguard.runtime import run_scenario  # noqa: E402
from cellguard.scenario import parse_scenario  # noqa: E402

LeRobotDataset = lerobot_dataset.LeRobotDataset


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    run_scenario(parse_scenario({"cell": "arm-pick-place", "seed": 4, "policy": "scripted", "acceptance_cycles": 2,
                                 "production_cycles": 1, "faults": [{"kind": "tool_slip", "at_cycle": 2}]}), out)
    with open_record(out) as rec:
        result = export_lerobot(rec, out / "dataset", task="pick and place")
        ticks = [rec.ticks(cycle=c, rate="decimated") for c in range(3)]
    return out / "dataset", result, ticks


def test_loads_with_lerobot_and_frames_equal_the_recorded_ticks(exported):
    root, result, ticks = exported
    ds = LeRobotDataset("local/cellguard-arm", root=root)
    assert ds.fps == 50 and ds.num_episodes == 3
    assert len(ds) == ds.meta.total_frames == result.frames == sum(len(t) for t in ticks)
    start = 0
    for episode, t in enumerate(ticks):
        meta = ds.meta.episodes[episode]
        assert (meta["dataset_from_index"], meta["dataset_to_index"]) == (start, start + len(t))
        last = ds[start + len(t) - 1]
        assert last["episode_index"].item() == episode and last["frame_index"].item() == len(t) - 1
        np.testing.assert_array_equal(last["action"].numpy(), t.q_cmd[-1].astype(np.float32))
        np.testing.assert_array_equal(last["observation.state"].numpy(), t.q_meas[-1].astype(np.float32))
        assert last["timestamp"].item() == pytest.approx((len(t) - 1) / 50, abs=1e-5)
        assert last["task"] == "pick and place"
        start += len(t)
    assert ds.meta.stats["action"]["mean"].shape == (6,)
    assert ds.meta.episodes[2]["cellguard/success"] is False


def test_action_chunks_for_training_stop_at_the_episode_end(exported):
    """What an ACT-style trainer asks: 50 future actions per frame, padded past the episode's end."""
    root, _, ticks = exported
    ds = LeRobotDataset("local/cellguard-arm", root=root, delta_timestamps={"action": [i / 50 for i in range(50)]})
    n = len(ticks[0])
    item = ds[n - 10]
    assert item["action"].shape == (50, 6)
    assert not item["action_is_pad"][:10].any() and item["action_is_pad"][10:].all()
    np.testing.assert_array_equal(item["action"][9].numpy(), ticks[0].q_cmd[-1].astype(np.float32))


def test_same_layout_as_lerobots_own_writer(exported, tmp_path):
    """A dataset lerobot writes with the same features has the same metadata keys and column types."""
    root, _, _ = exported
    info = json.loads((root / "meta/info.json").read_text())
    features = {k: {**v, "shape": tuple(v["shape"])} for k, v in info["features"].items()
                if not k.startswith(("timestamp", "frame_index", "episode_index", "index", "task_index"))}
    own = LeRobotDataset.create("local/reference", fps=50, root=tmp_path / "ref", robot_type="arm",
                                features=features, use_videos=False)
    for i in range(3):
        own.add_frame({k: np.full(v["shape"], i, np.float32) for k, v in features.items()} | {"task": "pick and place"})
    own.save_episode()
    own.finalize()
    ref_info = json.loads((tmp_path / "ref/meta/info.json").read_text())
    assert set(ref_info) == set(info) and ref_info["features"] == info["features"]
    ours = pq.read_schema(root / "data/chunk-000/file-000.parquet")
    theirs = pq.read_schema(tmp_path / "ref/data/chunk-000/file-000.parquet")
    assert {f.name: f.type for f in ours} == {f.name: f.type for f in theirs}
    ours = set(pq.read_schema(root / "meta/episodes/chunk-000/file-000.parquet").names)
    theirs = set(pq.read_schema(tmp_path / "ref/meta/episodes/chunk-000/file-000.parquet").names)
    assert theirs <= ours and {n for n in ours - theirs if not n.startswith("cellguard/")} == set()
    assert set(json.loads((root / "meta/stats.json").read_text())) == set(
        json.loads((tmp_path / "ref/meta/stats.json").read_text()))
