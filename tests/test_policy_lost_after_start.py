"""A policy that turns bad after it has started (a NaN in every chunk, every call failing, every answer later
than its own horizon) is lost once the guard's watchdog has held the robot and every answer since the last chunk
taken was refused: before, the rule applied only until the run's first chunk, so each cycle waited out its
12 s time-out, one event per request, and the run exited 0. A stale chunk (all its steps past) counts as a
refusal: it can never move the robot. A short run of bad answers among taken ones is no loss (nor one late
answer: test_policy_lost_openpi)."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from test_runtime_rejected_answers import _nan, _run
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.robot.registry import make_cell

ARM = "arm-pick-place"
SINCE = "none taken since t = "


def _failed(call, chunk):
    return RuntimeError("server error")


def _kinds(summary) -> list[str]:
    return [e["kind"] for e in summary["events"]]


@pytest.mark.parametrize("bad, why", [(_nan, "policy lost: the guard rejected every chunk, " + SINCE),
                                      (_failed, "policy lost: every call failed, " + SINCE)], ids=["nan", "failed"])
def test_a_policy_that_turns_bad_after_its_first_chunks_is_lost_and_the_run_stops(tmp_path, bad, why):
    """Five good chunks, then every answer bad: the watchdog holds the robot, the next refused answer loses it."""
    moved, summary = _run(tmp_path, lambda call, chunk: bad(call, chunk) if call > 5 else None)
    kinds = _kinds(summary)
    assert summary["stopped"].startswith(why), summary.get("stopped")
    assert kinds.count("policy_lost") == 1 and "watchdog_no_first_chunk" not in kinds
    assert kinds.index("watchdog_stop") < kinds.index("policy_lost")
    lost = next(e for e in summary["events"] if e["kind"] == "policy_lost")
    assert lost["category"] == 2 and lost["t_ns"] < 0.6e9  # 0.25 s the last chunk taken, 0.3 s the watchdog
    assert len(summary["cycles"]) == 1 and not summary["cycles"][0]["timed_out"]
    assert moved > 0.01  # it had started


def test_a_policy_whose_every_chunk_comes_stale_after_a_good_cycle_is_lost(tmp_path):
    """600 ms of latency on the scripted arm's 500 ms chunks from the second cycle on: every chunk arrives with all
    its steps past (chunk_stale), nothing moves, and the cycle waited out its time-out, exit 0."""
    _, summary = _run(tmp_path, lambda call, chunk: None,
                      faults=[{"kind": "policy_latency", "at_cycle": 1, "ms": 600}])
    kinds = _kinds(summary)
    assert summary["stopped"].startswith("policy lost: every chunk was stale, " + SINCE), summary.get("stopped")
    assert summary["stopped"].endswith("(the last: all 25 steps lie before now)")
    assert kinds.count("chunk_stale") == 2 and kinds.count("policy_lost") == 1
    assert [c["success"] for c in summary["cycles"]] == [True, False]
    assert not summary["cycles"][1]["timed_out"]


def test_a_short_run_of_bad_answers_among_taken_ones_is_no_loss(tmp_path):
    """Three rejected chunks (150 ms) then good ones, twice in each cycle: the watchdog never fires, nothing is lost."""
    _, summary = _run(tmp_path, lambda call, chunk: _nan(call, chunk) if call % 20 in (6, 7, 8) else None)
    kinds = _kinds(summary)
    assert "policy_lost" not in kinds and "stopped" not in summary and kinds.count("chunk_rejected") > 6
    assert [c["success"] for c in summary["cycles"]] == [True] * 3


def test_a_replay_whose_every_chunk_is_stale_from_the_start_exits_1(tmp_path):
    """Stamps 5 s before the start: 240 chunk_stale, the no-first-chunk watchdog's stop, exit 0 (stale answers were
    not counted as refused)."""
    q = make_cell(ARM).read().q
    np.savez(tmp_path / "old.npz", t=np.linspace(-5.0, -3.0, 40), actions=np.tile(q, (40, 25, 1)),
             dt=np.array(0.02))
    (tmp_path / "s.yaml").write_text(yaml.safe_dump({"cell": ARM, "acceptance_cycles": 1, "production_cycles": 0,
                                                     "policy": f"replay:{tmp_path / 'old.npz'}"}))
    result = CliRunner().invoke(app, ["run", str(tmp_path / "s.yaml"), "--out", str(tmp_path / "out")])
    assert result.exit_code == 1, result.output
    assert result.stderr.splitlines()[-1].startswith("error: the cell was stopped (policy_lost): policy lost: every "
                                                     "chunk was stale, none taken (the last: all 25 steps lie "
                                                     "before now)"), result.stderr

