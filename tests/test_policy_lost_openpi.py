"""Wall time, the real openpi server on loopback: a policy whose answers turn slow after the start-up latency check
(fast through the warm-up and its first chunk) sends only stale chunks, all their steps past: it can never move the
robot, and is lost once the watchdog has held it (before: 26 chunk_stale, every cycle to its 12 s time-out, exit 0).
One slow call among fast ones is no loss."""

from __future__ import annotations

import time

import pytest
import yaml

openpi = pytest.importorskip("test_openpi")  # the openpi server and the foreign arm's policy; skipped without them

from cellguard.runtime import Run, run_scenario  # noqa: E402
from cellguard.scenario import parse_scenario  # noqa: E402


class _SlowAfter(openpi.ForeignScriptedPolicy):
    """The foreign arm's 200 ms chunks (10 of 20 ms), each call numbered in ``slow`` taking 450 ms."""

    def __init__(self, slow):
        super().__init__()
        self.slow = slow

    def infer(self, obs: dict) -> dict:
        if self.calls + 1 in self.slow:
            time.sleep(0.45)
        return super().infer(obs)


def _served(tmp_path, slow) -> tuple[dict, list[str]]:
    """One 2 s cycle on wall time against the served policy: the summary and its events' kinds."""
    (tmp_path / "map.yaml").write_text(yaml.safe_dump(openpi.MAP))
    with openpi.serve(_SlowAfter(slow), {"action_names": openpi.FOREIGN_NAMES, "dt_s": 0.02}) as uri:
        scenario = parse_scenario({"cell": "arm-pick-place", "seed": 3, "acceptance_cycles": 1, "production_cycles": 0,
                                   "cycle": {"source": "time", "seconds": 2.0},
                                   "realtime": {"overrun_budget": 1_000_000},
                                   "policy": f"openpi:{uri}?map={tmp_path / 'map.yaml'}&timeout=2"})
        summary = run_scenario(scenario, tmp_path / "out", run=Run(scenario, realtime=True))
    return summary, [e["kind"] for e in summary["events"]]


def test_an_openpi_policy_whose_every_answer_turns_stale_is_lost(tmp_path):
    """450 ms a call after its second (the warm-up and the first chunk fast): the probe's server."""
    summary, kinds = _served(tmp_path, slow=range(3, 1000))
    assert summary["stopped"].startswith("policy lost: every chunk was stale, none taken since t = "), \
        summary.get("stopped")
    assert kinds.count("chunk_stale") == 2 and kinds.index("watchdog_stop") < kinds.index("policy_lost")
    assert not summary["cycles"][0]["timed_out"]


def test_one_stale_answer_of_a_slow_call_among_fresh_ones_is_no_loss(tmp_path):
    """One 450 ms call: its chunk stale, the watchdog fired meanwhile, the next answers fresh: the run goes on."""
    summary, kinds = _served(tmp_path, slow={6})
    assert kinds.count("chunk_stale") == 1 and "watchdog_stop" in kinds
    assert "policy_lost" not in kinds and "stopped" not in summary
