"""A tick between a cycle's end and the next cycle's start lies in no cycle. The recorder stamps each tick with the
cycle begun last, so the retreat home after a time cycle that ended mid-motion (434 ms of ticks here) was read as
that cycle's: in ``ticks()``, ``tick_parts``, ``record export`` and the LeRobot episode made of the cycle."""

from __future__ import annotations

import numpy as np
import pyarrow.csv as pacsv
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.record.reader import NO_CYCLE, RATES, open_record
from cellguard.robot.registry import make_cell
from cellguard.runtime import run_scenario
from cellguard.scenario import parse_scenario

runner = CliRunner()


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """Two time cycles of a policy turning the base past each cycle's end; the retreat home follows the last."""
    folder = tmp_path_factory.mktemp("retreat")
    home = np.array(make_cell("arm-pick-place").read().q, dtype=np.float64)
    t = np.arange(0.0, 3.0, 0.1)  # chunks of 25 steps of 20 ms turning the base at 0.5 rad/s
    actions = np.array([[home + np.array([0.5 * (s + k * 0.02), 0, 0, 0, 0, 0]) for k in range(1, 26)] for s in t])
    np.savez(folder / "turn.npz", t=t, actions=actions, dt=np.float64(0.02))
    run_scenario(parse_scenario({"cell": "arm-pick-place", "policy": f"replay:{folder / 'turn.npz'}",
                                 "acceptance_cycles": 2, "production_cycles": 0,
                                 "cycle": {"source": "time", "seconds": 1.0}}), folder / "run")
    return folder


def _last_end(rec) -> int:
    spans = rec.cycle_spans()
    assert sorted(spans) == [0, 1] and all(end is not None for _, end in spans.values())
    retreat = [e.t_ns for e in rec.events() if e.kind == "retreat_begin"]
    assert retreat and retreat[0] >= spans[1][1]  # the retreat is recorded after the last cycle's end marker
    return spans[1][1]


def test_ticks_after_a_cycle_end_are_in_no_cycle(run):
    with open_record(run / "run") as rec:
        end = _last_end(rec)
        for rate in RATES:
            ticks = rec.ticks(rate=rate)
            after = ticks.t_ns > end
            assert after.sum() > 10, rate  # the retreat's ticks are recorded
            assert (ticks.cycle[after] == NO_CYCLE).all(), rate
            assert (ticks.cycle[~after] >= 0).all(), rate
            for cycle, (start, stop) in rec.cycle_spans().items():
                own = rec.ticks(cycle=cycle, rate=rate)
                assert start <= own.t_ns[0] and own.t_ns[-1] <= stop, (rate, cycle)
                assert np.array_equal(own.t_ns, ticks.t_ns[ticks.cycle == cycle]), (rate, cycle)
            parts = list(rec.tick_parts(rate, 600))
            assert len(parts) > 1
            assert np.array_equal(np.concatenate([p.cycle for p in parts]), ticks.cycle), rate
            span = rec.ticks(rate=rate, start_ns=end - 50_000_000, end_ns=end + 50_000_000)
            assert np.array_equal(span.cycle, np.where(span.t_ns > end, NO_CYCLE, 1)), rate


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_record_export_leaves_their_cycle_empty(run, fmt):
    out = run / f"ticks.{fmt}"
    result = runner.invoke(app, ["record", "export", str(run / "run"), "--format", fmt, "-o", str(out)])
    assert result.exit_code == 0, result.output
    table = pq.read_table(out) if fmt == "parquet" else pacsv.read_csv(out)
    t, cycle = table["t_ns"].to_numpy(), table["cycle"]
    with open_record(run / "run") as rec:
        end = _last_end(rec)
    assert (t > end).sum() > 10
    assert cycle.is_null().to_numpy(zero_copy_only=False).tolist() == (t > end).tolist()


def test_the_last_episode_ends_with_its_cycle(run):
    out = run / "dataset"
    result = runner.invoke(app, ["record", "to-lerobot", str(run / "run"), "-o", str(out)])
    assert result.exit_code == 0, result.output
    episodes = pq.read_table(out / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    with open_record(run / "run") as rec:
        spans = rec.cycle_spans()
    assert [e["cellguard/cycle"] for e in episodes] == [0, 1]
    for episode in episodes:  # a frame every 20 ms (50 fps) from the cycle's start to its end, none of the retreat
        start, end = spans[episode["cellguard/cycle"]]
        assert episode["length"] <= (end - start) * 50e-9 + 1, episode
