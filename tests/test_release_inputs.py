"""Release inputs a fuzzing probe found taken, or ending in a traceback: an envelope a run refuses, a plan's gates or
runs that are no list, a bundle deleted from the store, a pointers row edited into no cell, --map on a policy that
takes no action map."""

from __future__ import annotations

import pytest
from release_helpers import CELL, cli, edit_store, promoted_site, write_plan

from cellguard.release import load_plan
from cellguard.release.errors import GateError


def _one_line(result, code: int = 2) -> str:
    assert result.exit_code == code and result.stderr.count("\n") == 1, result.output
    assert "Traceback" not in result.output
    return result.stderr


@pytest.mark.parametrize(("text", "says"), [("scale_rate: .inf", "guard.scale_rate: inf is not a finite number"),
                                            ("scale_accel: .inf", "guard.scale_accel: inf is not a finite number"),
                                            ("uncertainty_threshold: .inf", "guard.uncertainty_threshold: inf is not"),
                                            ("[]", "guard: "), ("false", "guard: "), ("0", "guard: "),
                                            ('""', "guard: ")])
def test_an_envelope_a_scenario_guard_refuses_is_refused_at_create(tmp_path, text, says):
    """``.inf`` was frozen into the manifest (``Infinity``, no JSON) and promoted, refused only by `release run`; a
    document that is no mapping (``[]``, ``false``) was the default envelope."""
    guard = tmp_path / "guard.yaml"
    guard.write_text(text + "\n")
    result = cli("create", "--policy", "scripted", "--profile", CELL, "--envelope", str(guard),
                 "--site", str(tmp_path / "site"))
    assert says in _one_line(result) and f"--envelope {guard}: " in result.stderr
    assert not (tmp_path / "site").exists()


@pytest.mark.parametrize("key", ["gates", "runs"])
@pytest.mark.parametrize("value", ["1.5", "true", "3"])
def test_a_plan_stage_whose_gates_or_runs_are_no_list_is_one_line(tmp_path, key, value):
    """``gates: 1.5`` was ``TypeError: 'float' object is not iterable`` from promote and run, exit 1."""
    site, (rid,) = promoted_site(tmp_path)
    plan = tmp_path / "plan.yaml"
    plan.write_text(f"stages:\n  sim:\n    {key}: {value}\n")
    with pytest.raises(GateError, match=f"stages.sim.{key}: Input should be a valid list"):
        load_plan(plan)
    for command in (("promote", rid, "--cell", CELL, "--to", "bench"), ("run", "--cell", CELL, "--stage", "sim")):
        result = cli(*command, "--plan", str(plan), "--site", str(site))
        assert f"stages.sim.{key}: Input should be a valid list" in _one_line(result)


def test_a_stage_that_is_no_mapping_is_refused_not_an_empty_stage(tmp_path):
    """``sim: false`` read as a stage with no runs; ``sim:`` left empty still is one."""
    with pytest.raises(GateError, match="stages.sim: expected a mapping"):
        load_plan(write_plan(tmp_path / "plan.yaml", {"sim": False}))
    assert load_plan(write_plan(tmp_path / "plan.yaml", {"sim": None}))["sim"].runs == []


def test_verify_names_every_release_named_with_its_bundle_deleted(tmp_path):
    """`DELETE FROM bundles` passed verify ("chain verified"), while promote then said the release was unknown."""
    site, (old, new) = promoted_site(tmp_path, ("v1", "v2"))
    assert cli("verify", "--site", str(site)).exit_code == 0
    edit_store(site, "DELETE FROM bundles")
    result = cli("verify", "--site", str(site))
    assert result.exit_code == 1
    said = " ".join(result.stdout.split())  # rich wraps its lines
    assert f"broken: release {new}: no bundle (deleted outside cellguard); named by current of sim on {CELL}" in said
    assert f"broken: release {old}: no bundle (deleted outside cellguard); named by log entry 1, log entry 2" in said


@pytest.mark.parametrize("edit", ["UPDATE pointers SET cell=NULL", "UPDATE pointers SET cell=CAST(cell AS BLOB)",
                                  "UPDATE pointers SET current=CAST(current AS BLOB)"])
def test_status_on_a_pointers_row_edited_into_no_name_is_one_line(tmp_path, edit):
    """A NULL cell was ``TypeError: unsupported format string passed to NoneType.__format__``, exit 1."""
    site, (rid,) = promoted_site(tmp_path)
    edit_store(site, edit)
    for extra in ((), ("--json",)):
        result = cli("status", *extra, "--site", str(site))
        assert "the pointers row cell " in _one_line(result) and "edited outside cellguard" in result.stderr
    assert cli("verify", "--site", str(site)).exit_code == 1


@pytest.mark.parametrize("edit", ["UPDATE log SET body=X'00ff'", "UPDATE bundles SET manifest=X'00ff'",
                                  "UPDATE bundles SET id=X'00ff'"])
def test_bytes_that_are_no_utf8_are_an_edit_verify_names(tmp_path, edit):
    """sqlite3's "Could not decode to UTF-8" ended verify in a traceback, exit 1 with no break named."""
    site, _ = promoted_site(tmp_path)
    edit_store(site, edit)
    result = cli("verify", "--site", str(site))
    assert result.exit_code == 1 and "broken: " in result.stdout and "Traceback" not in result.output


@pytest.mark.parametrize("policy", ["scripted", "replay:incident.npz"])
def test_map_on_a_policy_that_takes_none_names_map(tmp_path, policy):
    """`--policy scripted --map F` said "unknown policy source 'scripted?map=F'; known: ..., scripted"."""
    amap = tmp_path / "map.yaml"
    amap.write_text("robot: arm-pick-place\nactions:\n  - {name: a, joint: elbow, unit: rad}\n")
    result = cli("create", "--policy", policy, "--map", str(amap), "--profile", CELL, "--site", str(tmp_path / "s"))
    said = _one_line(result)
    assert said.startswith(f"error: --map: the {policy.partition(':')[0]} policy drives the robot's joints directly; "
                           "it takes no action map") and "?map=" not in said
    bogus = cli("create", "--policy", "bogus", "--map", str(amap), "--profile", CELL, "--site", str(tmp_path / "s"))
    assert "unknown policy source 'bogus';" in _one_line(bogus) and "?map=" not in bogus.stderr


@pytest.mark.parametrize(("stage", "says"), [
    ("    shadow: yes\n", "stages.sim.shadow: Input should be a valid boolean (got 'yes': text to YAML 1.2; write true"),
    ("    gates:\n      - {metric: success_rate, min: 1.0, hard: no}\n",
     "stages.sim.gates[0].hard: Input should be a valid boolean (got 'no': text to YAML 1.2; write true or false"),
])
def test_a_plan_boolean_written_yes_or_no_says_to_write_true_or_false(tmp_path, stage, says):
    """YAML 1.1's yes/no are text to the loader (YAML 1.2): a plan that used them was refused without a word why."""
    plan = tmp_path / "plan.yaml"
    plan.write_text("stages:\n  sim:\n" + stage)
    with pytest.raises(GateError) as refused:
        load_plan(plan)
    assert says in str(refused.value)
