"""Shadow mode: the candidate never actuates; its distance and would-be clamps are recorded."""

from __future__ import annotations

import json

import numpy as np
import pytest
from release_helpers import CELL, replay_file

from cellguard.control.config import GuardConfig
from cellguard.errors import ConfigError
from cellguard.record.reader import open_record
from cellguard.release.evidence import load_run
from cellguard.release.metrics import METRICS
from cellguard.release.shadow import ShadowRun
from cellguard.runtime import run_scenario
from cellguard.scenario import parse_scenario


def _shadow_run(tmp_path, candidate: str, name: str):
    scenario = parse_scenario({"cell": CELL, "seed": 3, "policy": "scripted", "acceptance_cycles": 1,
                               "production_cycles": 0})
    run = ShadowRun(scenario, candidate, GuardConfig())
    folder = tmp_path / name
    summary = run_scenario(scenario, folder, run=run)
    run.write_shadow(folder)
    return summary, folder


def test_a_wild_candidate_is_flagged_and_the_incumbent_drives_untouched(tmp_path):
    wild = replay_file(tmp_path / "wild.npz", offset=0.4)  # 0.4 rad from home on every joint, at once
    summary, folder = _shadow_run(tmp_path, f"replay:{wild}", "wild")
    assert summary["phases"]["acceptance"]["success_rate"] == 1.0
    assert not [e for e in summary["events"] if e["kind"] != "chunk_steps_dropped"]  # the robot saw nothing of it
    with open_record(folder) as rec:
        assert rec.context["policy"]["source"] == "scripted"
    rows = json.loads((folder / "shadow.json").read_text())["chunks"]
    assert rows and np.median([r["distance_rad"] for r in rows if r["distance_rad"] is not None]) > 0.2
    assert any("chunk_rejected" in r["events"] or "limit_intervention" in r["events"] for r in rows)
    run = load_run(folder, "wild")
    assert METRICS["shadow_would_clamp"].compute([run]).value > 0.0
    assert METRICS["shadow_distance_p95_mrad"].compute([run]).value > 200.0


def test_the_same_program_in_shadow_is_at_zero_distance(tmp_path):
    _, folder = _shadow_run(tmp_path, "scripted", "same")
    run = load_run(folder, "same")
    assert np.isclose(METRICS["shadow_distance_p95_mrad"].compute([run]).value, 0.0, atol=1e-6)
    assert METRICS["shadow_would_clamp"].compute([run]).value == 0.0
    assert METRICS["shadow_would_stop"].compute([run]).value == 0.0


def test_shadow_with_the_policy_in_its_own_process_is_refused():
    """The inference process would run the incumbent alone: no candidate, an empty shadow, gates inconclusive."""
    scenario = parse_scenario({"cell": CELL, "seed": 3, "policy": "scripted", "acceptance_cycles": 1,
                               "production_cycles": 0, "realtime": {"inference": "process"}})
    with pytest.raises(ConfigError, match="realtime.inference must be 'thread'"):
        ShadowRun(scenario, "scripted", GuardConfig())


def test_a_candidate_whose_chunks_are_never_taken_would_stop_the_cell(tmp_path):
    """Every chunk NaN: live, no first chunk within the watchdog is a stop; the shadow counted 0 would-stops."""
    nan = tmp_path / "nan.npz"
    with np.load(replay_file(tmp_path / "home.npz")) as z:
        actions = z["actions"].copy()
    actions[..., 0] = np.nan
    np.savez(nan, t=np.array([0.0]), actions=actions, dt=np.array(0.05))
    _, folder = _shadow_run(tmp_path, f"replay:{nan}", "nan")
    rows = json.loads((folder / "shadow.json").read_text())["chunks"]
    assert rows and all("chunk_rejected" in r["events"] for r in rows)
    assert [r["events"].count("watchdog_no_first_chunk") for r in rows].count(1) == 1
    assert METRICS["shadow_would_stop"].compute([load_run(folder, "nan")]).value == 1.0
