"""The pilot's shadow sees the candidate's own envelope: what its guard would command, beside what the live one did.

A candidate whose envelope caps the tool at 0.25 m/s (its own guard config: it fails every cycle in sim) read
distance 0 and would-clamp 0.6 % beside the taught program: its raw chunks are the incumbent's, and the cap slows the
playback without an event. Its shadow guard now follows the live one tick by tick (the measured state, the safety
inputs, the approach, a recovery's chunks) and the distance is between the two guards' commands over each chunk's
span; an intervention the live guard made on the same tick for the same reason is not the candidate's. A twin of the
incumbent reads 0 everywhere (a first fix read 746 mrad under the reduced-speed input and 753 mrad across
recoveries); the incumbent drives as without a shadow; a shadow file written before keeps being read.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from cellguard.control.config import GuardConfig
from cellguard.record.reader import open_record
from cellguard.release.evidence import SHADOW_FILE, load_run
from cellguard.release.metrics import METRICS
from cellguard.release.shadow import ShadowRun
from cellguard.robot.protocol import SafetyInputs
from cellguard.runtime import Run, run_scenario
from cellguard.scenario import parse_scenario

CAPPED = {"tool_speed_max": 0.25}  # the probe's candidate envelope [m/s]
NAMES = ("shadow_distance_p95_mrad", "shadow_would_clamp", "shadow_would_stop")
TWIN = dict.fromkeys(NAMES, 0.0)
RECOVERY = {"max_per_cycle": 4, "behaviours": [
    {"do": "retry_grasp", "trigger": "grasp_missed", "attempts": 2, "search_mm": 5.0, "then": "operator"},
    {"do": "operator", "hold_s": 0.5}]}


def _scenario(cell: str = "arm-pick-place", seed: int = 9, **more):
    return parse_scenario({"cell": cell, "seed": seed, "policy": "scripted", "acceptance_cycles": 2,
                           "production_cycles": 0, **more})


def _shadow(folder, scenario, candidate_guard: dict | None = None, safety=None):
    """The taught program driving ``scenario`` with itself as the candidate under ``candidate_guard`` (default: the
    incumbent's), ``safety(t_ns)`` the controller's inputs if given: (summary, shadow rows, metric values)."""
    run = ShadowRun(scenario, "scripted", GuardConfig(**candidate_guard) if candidate_guard is not None
                    else scenario.guard)
    if safety is not None:
        run.cell.safety = lambda: safety(run.clock.now())
    summary = run_scenario(scenario, folder, run=run)
    run.write_shadow(folder)
    evidence = load_run(folder, "shadow")
    rows = json.loads((folder / SHADOW_FILE).read_text())["chunks"]
    return summary, rows, {name: METRICS[name].compute([evidence]).value for name in NAMES}


def _commands_measured(rows) -> list[float]:
    """The chunks' command distances, every chunk taken having one (a chunk is counted over its span)."""
    measured = [r["command_distance_rad"] for r in rows if r["command_distance_rad"] is not None]
    assert len(measured) > 0.9 * len(rows)
    return measured


def _reduced_mid_run(t_ns: int) -> SafetyInputs:
    """The controller's reduced-speed input from 1 s to 3 s into the run: mid-cycle, on and off."""
    return SafetyInputs(reduced_speed=1e9 <= t_ns < 3e9)


@pytest.mark.parametrize("cell, seed", [("arm-pick-place", 9), ("arm-pick-place", 4), ("quadruped-turns", 9)])
def test_a_twin_of_the_incumbent_reads_zero(tmp_path, cell, seed):
    summary, rows, values = _shadow(tmp_path / "twin", _scenario(cell, seed))
    assert values == TWIN
    assert max(_commands_measured(rows)) == 0.0
    assert all(c["success"] for c in summary["cycles"])


def test_a_twin_reads_zero_under_the_live_reduced_speed_input(tmp_path):
    """Its guard is given the input the live one is given: it slows alike (given none, it read 746 mrad)."""
    summary, rows, values = _shadow(tmp_path / "reduced", _scenario(), safety=_reduced_mid_run)
    assert [e["kind"] for e in summary["events"]].count("reduced_speed_input") == 1  # the live guard slowed
    assert values == TWIN
    assert max(_commands_measured(rows)) == 0.0


def test_a_twin_reads_zero_across_recoveries(tmp_path):
    """A recovery's chunks go into the shadow guard as into the live one (it kept playing the candidate's last chunk
    and read 753 mrad; rebuilt at rest after the recovery it read 5 mrad)."""
    scenario = _scenario(seed=7, recovery=RECOVERY, acceptance_cycles=3,
                         faults=[{"kind": "intermittent_slip", "rate": 0.5, "dx_mm": 5.0, "seed": 3}])
    summary, rows, values = _shadow(tmp_path / "recovery", scenario)
    assert sum(c["recoveries"] for c in summary["cycles"]) >= 1
    assert values == TWIN
    assert max(_commands_measured(rows)) == 0.0


def test_a_capped_incumbent_against_itself_is_no_clamp_of_the_candidates(tmp_path):
    """Both envelopes slow the same playback on the same ticks: the live guard's own, not the candidate's."""
    _, rows, values = _shadow(tmp_path / "capped", _scenario(guard=CAPPED))
    assert values == TWIN
    assert max(_commands_measured(rows)) == 0.0


def test_a_candidate_its_own_tool_speed_cap_slows_is_far_from_the_incumbent(tmp_path):
    summary, rows, values = _shadow(tmp_path / "slow", _scenario(), CAPPED)
    assert all(c["success"] for c in summary["cycles"])  # the incumbent drove, at its own speed
    assert values["shadow_distance_p95_mrad"] > 300.0  # its commands lag the incumbent's by tenths of a radian
    assert values["shadow_would_clamp"] > 0.9  # the cap slowed nearly every chunk's playback
    assert values["shadow_would_stop"] == 0.0
    assert max(r["distance_rad"] for r in rows if r["distance_rad"] is not None) == 0.0  # the raw chunks alike


def _plain_run(folder):
    """The same scenario and inputs as the shadowed run, without a shadow: its summary."""
    scenario = _scenario()
    run = Run(scenario)
    run.cell.safety = lambda: _reduced_mid_run(run.clock.now())
    return run_scenario(scenario, folder, run=run)


def test_the_incumbents_commands_are_the_same_with_and_without_a_shadow(tmp_path):
    """A capped candidate, under the reduced-speed input: the shadow reads the live loop and never changes it."""
    plain = _plain_run(tmp_path / "plain")
    _shadow(tmp_path / "shadow", _scenario(), CAPPED, safety=_reduced_mid_run)
    with open_record(tmp_path / "plain") as a, open_record(tmp_path / "shadow") as b:
        ta, tb = a.ticks(), b.ticks()
    assert len(ta.t_ns) > 1000 and len(ta.t_ns) == len(tb.t_ns)
    for field in ("t_ns", "q_ref", "q_cmd", "q_meas"):
        np.testing.assert_array_equal(getattr(ta, field), getattr(tb, field), err_msg=field)
    assert plain["cycles"][1]["place_error_mm"] == json.loads(
        (tmp_path / "shadow" / "summary.json").read_text())["cycles"][1]["place_error_mm"]


def test_a_shadow_file_written_before_command_distances_is_read_by_the_metrics(tmp_path):
    """Its rows hold the raw chunks' ``distance_rad`` only: that is the distance it is read by."""
    folder = tmp_path / "old"
    _shadow(folder, _scenario(), CAPPED)
    doc = json.loads((folder / SHADOW_FILE).read_text())
    for k, row in enumerate(doc["chunks"]):  # as an older cellguard wrote them
        row.pop("command_distance_rad", None)
        row.update(distance_rad=0.001 * k, clamped=k % 4 == 0, stopped=False, events=[])
    (folder / SHADOW_FILE).write_text(json.dumps(doc))
    evidence = load_run(folder, "old")
    n = len(doc["chunks"])
    assert METRICS["shadow_distance_p95_mrad"].compute([evidence]).value == pytest.approx(0.95 * (n - 1), rel=1e-9)
    assert METRICS["shadow_would_clamp"].compute([evidence]).value == pytest.approx(len(range(0, n, 4)) / n)
    assert METRICS["shadow_would_stop"].compute([evidence]).value == 0.0


def _stop(category: int, begin_s: float, end_s: float | None = None):
    """The controller's stop input of ``category`` from ``begin_s`` on, till ``end_s`` (None: held to the end)."""
    def safety(t_ns: int) -> SafetyInputs:
        held = begin_s * 1e9 <= t_ns and (end_s is None or t_ns < end_s * 1e9)
        return SafetyInputs(stop=category if held else None)
    return safety


@pytest.mark.parametrize("cell, category, begin_s, end_s", [
    ("arm-pick-place", 0, 1.5, 1.8), ("arm-pick-place", 1, 1.5, 1.8), ("arm-pick-place", 1, 4.0, None),
    ("quadruped-turns", 0, 1.5, 1.8)])
def test_a_twin_reads_zero_after_a_stop_that_removed_power(tmp_path, cell, category, begin_s, end_s):
    """Its guard stays unpowered while the live one does, reset only with it (reset on each candidate chunk taken
    after the stop, it drove on while the robot stood: 214 to 1100 mrad, 4 to 156 would-stops)."""
    summary, rows, values = _shadow(tmp_path / "stop", _scenario(cell), safety=_stop(category, begin_s, end_s))
    kinds = [e["kind"] for e in summary["events"]]
    assert "power_removed" in kinds  # the live guard removed power mid-cycle
    assert ("reset" in kinds) == (end_s is not None)  # the next cycle's reset, none while the input is held
    assert values == TWIN
    assert max(_commands_measured(rows)) == 0.0


def test_a_stale_chunk_the_live_guard_refused_too_is_no_clamp_of_the_candidates(tmp_path):
    """The incumbent answers 600 ms late: the live guard refuses its chunks as stale, and the candidate's, taken on
    the same tick, alike (counted as the candidate's clamp, would_clamp read 0.022)."""
    scenario = _scenario(faults=[{"kind": "policy_latency", "at_cycle": 1, "ms": 600}])
    summary, _, values = _shadow(tmp_path / "stale", scenario)
    assert "chunk_stale" in [e["kind"] for e in summary["events"]]
    assert values == TWIN
