"""Shadow mode sees the candidate's own envelope: what its guard would send, not its raw chunks.

A release whose envelope caps the tool at 0.25 m/s failed every sim cycle (grasped false, place error 305 mm), yet
beside the taught program in the pilot it read as its twin: distance 0 (the raw chunks are the same program),
would-clamp 1 chunk of 178 (the cap slows the playback without an event). The incumbent drives untouched.
"""

from __future__ import annotations

import json

import numpy as np
from release_helpers import CELL

from cellguard.control.config import GuardConfig
from cellguard.release.evidence import load_run
from cellguard.release.metrics import METRICS
from cellguard.release.shadow import ShadowRun
from cellguard.runtime import run_scenario
from cellguard.scenario import parse_scenario

SLOW = {"watchdog_s": 0.3, "tool_speed_max": 0.25}  # the probe's guard-25.yaml


def _shadow(tmp_path, candidate_guard: dict, incumbent_guard: dict | None = None):
    """The taught program driving, the taught program as the candidate under ``candidate_guard``: (summary, rows,
    metric values)."""
    scenario = parse_scenario({"cell": CELL, "seed": 9, "policy": "scripted", "acceptance_cycles": 2,
                               "production_cycles": 0, "guard": incumbent_guard or {}})
    run = ShadowRun(scenario, "scripted", GuardConfig(**candidate_guard))
    folder = tmp_path / "shadow"
    summary = run_scenario(scenario, folder, run=run)
    run.write_shadow(folder)
    rows = json.loads((folder / "shadow.json").read_text())["chunks"]
    evidence = load_run(folder, "shadow")
    values = {name: METRICS[name].compute([evidence]).value
              for name in ("shadow_distance_p95_mrad", "shadow_would_clamp", "shadow_would_stop")}
    return summary, rows, values


def test_a_candidate_its_own_tool_speed_cap_slows_is_no_twin_of_the_incumbent(tmp_path):
    summary, rows, values = _shadow(tmp_path, SLOW)
    assert summary["phases"]["acceptance"]["success_rate"] == 1.0  # the incumbent drove, at its own speed
    assert values["shadow_distance_p95_mrad"] > 300.0  # its commands lag the incumbent's by tenths of a radian
    assert values["shadow_would_clamp"] > 0.5  # the cap slowed most of its chunks
    assert sum("speed_scaled" in r["events"] for r in rows) > len(rows) / 2
    assert max(r["chunk_distance_rad"] for r in rows if r["chunk_distance_rad"] is not None) < 1e-9  # same chunks


def test_the_same_program_under_the_same_envelope_is_at_zero_distance(tmp_path):
    _, rows, values = _shadow(tmp_path, {})
    measured = [r["distance_rad"] for r in rows if r["distance_rad"] is not None]
    assert len(measured) > 0.9 * len(rows)
    assert max(measured) == 0.0  # from the first chunk on: pushed on the tick the incumbent's is, after its approach
    assert values == {"shadow_distance_p95_mrad": 0.0, "shadow_would_clamp": 0.0, "shadow_would_stop": 0.0}


def test_an_incumbent_under_the_same_cap_is_matched_command_for_command(tmp_path):
    """Both slowed alike: the commands agree, so the distance is the envelope's effect against the live one's."""
    _, rows, values = _shadow(tmp_path, SLOW, incumbent_guard=SLOW)
    measured = [r["distance_rad"] for r in rows if r["distance_rad"] is not None]
    assert len(measured) > 0.9 * len(rows) and np.allclose(measured, 0.0, atol=1e-9)
    assert values["shadow_would_clamp"] > 0.5  # its own envelope does slow it: a clamp, as the incumbent's is
