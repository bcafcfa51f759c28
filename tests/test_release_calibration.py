"""A release binds a calibration of its cell's profile (``identify --write``): the release id covers its hash,
every stage's run takes it, and a calibration changed since ``release create`` is refused as a policy file is."""

from __future__ import annotations

import json

import pytest
from release_helpers import CELL, cli, pointers, write_plan
from typer.testing import CliRunner

from cellguard.calibrate.excitation import excitation_scenario, excite
from cellguard.cli import app
from cellguard.record.reader import open_record
from cellguard.release import Store, create_bundle, load_plan, promote, run_stage
from cellguard.release.errors import BundleMismatch
from cellguard.robot.arm_cell import ASSETS
from cellguard.robot.physics import Physics

VERSION = "2026-11-26-cal-50493de6"
CALIBRATION = f"""calibration:
  version: {VERSION}
  mjcf: arm_profile.{VERSION}.xml
  date: '2026-11-26'
  records: [f4281797d6fd4231abc5291688d6e358]
  previous: '2026-11-01'
"""


def calibrated(tmp_path, elbow_friction: str = "0.23 N*m"):
    """The arm's profile as ``identify --write`` leaves it: other measured values, a calibration section."""
    stock = (ASSETS / "arm_profile.yaml").read_text()
    elbow = '{joint: elbow,         parameter: friction, value: "0.2 N*m"'
    assert elbow in stock
    text = stock.replace('version: "2026-11-01"', f"version: {VERSION}").replace(
        elbow, elbow.replace('"0.2 N*m"', f'"{elbow_friction}"'))
    path = tmp_path / "arm_profile.yaml"
    path.write_text(text + CALIBRATION)
    return path


def one_run_plan(tmp_path, runs=("one",)):
    runs = [{"name": name, "seed": 5, "acceptance_cycles": 1} for name in runs]
    return load_plan(write_plan(tmp_path / "plan.yaml", {"sim": {"runs": runs,
                                                                 "gates": [{"metric": "success_rate", "min": 0}]}}))


def test_a_calibrated_profile_is_bound_to_the_release_and_its_runs_take_it(tmp_path):
    """``release create --profile`` refused the profile ``identify --write`` wrote ("install it with the cell
    first"), so a release always ran on the stock profile and its records said ``calibration none``."""
    site, profile = tmp_path / "site", calibrated(tmp_path)
    made = cli("create", "--policy", "scripted", "--profile", str(profile), "--site", str(site), "--json")
    assert made.exit_code == 0, made.output
    manifest = json.loads(made.stdout)["manifest"]
    assert manifest["calibration"]["path"] == str(profile.resolve()) and manifest["calibration"]["version"] == VERSION
    stock = create_bundle("scripted", None, CELL, None)
    assert json.loads(made.stdout)["id"] != stock.id and "calibration" not in stock.manifest  # the id covers it
    store = Store(site)
    promote(store, json.loads(made.stdout)["id"], CELL, "sim")
    result = run_stage(store, one_run_plan(tmp_path)["sim"], CELL, "sim")
    with open_record(result.folders[0]) as rec:
        assert rec.context["embodiment"]["calibration"]["version"] == VERSION
        assert rec.context["embodiment"]["sha256"] == manifest["calibration"]["sha256"]


def test_a_calibration_changed_since_create_is_one_line_exit_2_and_nothing_moves(tmp_path):
    site, profile = tmp_path / "site", calibrated(tmp_path)
    made = cli("create", "--policy", "scripted", "--profile", str(profile), "--site", str(site), "--json")
    assert made.exit_code == 0, made.output
    calibrated(tmp_path, elbow_friction="0.25 N*m")  # recalibrated in place after the release was frozen
    result = cli("promote", json.loads(made.stdout)["id"], "--cell", CELL, "--to", "sim", "--site", str(site))
    assert result.exit_code == 2 and pointers(site) == []
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and f"calibration {profile.resolve()} changed since create" in lines[0]


def test_a_calibration_swapped_between_two_runs_of_a_stage_stops_it(tmp_path):
    """What the run's robot loaded is compared, as the policy is: the runs before stay, the next does not start."""
    store, profile = Store(tmp_path / "site"), calibrated(tmp_path)
    bundle = create_bundle("scripted", None, str(profile), None)
    store.add_bundle(bundle)
    promote(store, bundle.id, CELL, "sim")
    started = []

    def swap(line):
        started.append(line)
        if len(started) == 2:
            calibrated(tmp_path, elbow_friction="0.25 N*m")

    with pytest.raises(BundleMismatch, match="calibration .* changed since create"):
        run_stage(store, one_run_plan(tmp_path, ("first", "second"))["sim"], CELL, "sim", on_run=swap)
    assert len(started) == 2 and [p.name for p in (tmp_path / "site" / "runs" / CELL / "sim").iterdir()] == ["0001-first"]


def test_a_profile_with_other_limits_is_refused_saying_what_to_do(tmp_path):
    profile = calibrated(tmp_path)
    profile.write_text(profile.read_text().replace('["-2.5 rad", "2.5 rad"]', '["-2.4 rad", "2.4 rad"]', 1))
    result = cli("create", "--policy", "scripted", "--profile", str(profile), "--site", str(tmp_path / "site"))
    assert result.exit_code == 2 and not (tmp_path / "site").exists()
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "other joints or limits" in lines[0] and "identify --write" in lines[0]
    assert f"--profile {CELL}" in lines[0]


def test_a_manifest_from_before_calibrations_still_verifies_and_runs_on_the_cells_profile(tmp_path):
    store = Store(tmp_path / "site")
    bundle = create_bundle("scripted", None, str(ASSETS / "arm_profile.yaml"), None)  # the cell's own, as a file
    assert "calibration" not in bundle.manifest and bundle.calibration is None
    assert bundle.id == create_bundle("scripted", None, CELL, None).id
    store.add_bundle(bundle)
    promote(store, bundle.id, CELL, "sim")
    result = run_stage(store, one_run_plan(tmp_path)["sim"], CELL, "sim")
    with open_record(result.folders[0]) as rec:
        assert "calibration" not in rec.context["embodiment"]


@pytest.fixture(scope="module")
def excited(tmp_path_factory):
    """An excitation record of the arm (elbow friction x1.5) that ``identify --write`` calibrates from."""
    out = tmp_path_factory.mktemp("recalibrated") / "excite"
    excite(excitation_scenario(CELL, 3.0), out, physics=Physics(friction={"elbow": 1.5}))
    return out


def identify_write(record, profile) -> str:
    """Calibrate ``profile`` in place as a site does (the old profile kept beside it); the new version."""
    result = CliRunner().invoke(app, ["identify", str(record), "--params", "friction", "--write", str(profile),
                                      "--json"])
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout)["profile_version"]


def released_then_recalibrated(tmp_path, excited, stages=("sim",)):
    """Release A on a calibration written by ``identify --write``, passed through ``stages``; then the same file
    recalibrated in place. (store, A, A's calibration version, the profile, the plan)."""
    (tmp_path / "cal").mkdir()
    profile = (tmp_path / "cal").resolve() / "arm_profile.yaml"  # as the manifest names it
    profile.write_bytes((ASSETS / "arm_profile.yaml").read_bytes())
    version = identify_write(excited, profile)
    run = {"name": "one", "seed": 5, "acceptance_cycles": 1}
    plan = load_plan(write_plan(tmp_path / "plan.yaml", {
        s: {"runs": [run], "gates": [{"metric": "success_rate", "min": 0}], "shadow": s == "pilot"}
        for s in ("sim", "bench", "pilot", "production")}))
    store, a = Store(tmp_path / "site"), create_bundle("scripted", None, str(profile), None, note="A")
    store.add_bundle(a)
    for stage in stages:
        promote(store, a.id, CELL, stage)
        assert run_stage(store, plan[stage], CELL, stage).verdict == "pass"
    assert identify_write(excited, profile) != version
    return store, a, version, profile, plan


def test_a_release_still_runs_from_the_copy_kept_when_its_calibration_is_recalibrated_in_place(tmp_path, excited):
    """``identify --write`` rewrites the profile in place by design: a release bound to its path was refused at
    every run after (so was a rollback to it), though the bytes it froze stay beside it as NAME.VERSION.yaml."""
    store, a, version, profile, plan = released_then_recalibrated(tmp_path, excited)
    kept = profile.with_name(f"arm_profile.{version}.yaml")
    assert kept.is_file() and profile.read_bytes() != kept.read_bytes()
    result = run_stage(store, plan["sim"], CELL, "sim")
    assert result.verdict == "pass"
    with open_record(result.folders[0]) as rec:
        assert rec.context["embodiment"]["calibration"]["version"] == version
        assert rec.context["embodiment"]["sha256"] == a.manifest["calibration"]["sha256"]
        assert rec.context["scenario"]["calibration"] == str(kept)


def test_a_release_on_the_new_calibration_passes_the_pilot_beside_an_incumbent_bound_to_the_old(tmp_path, excited):
    """The pilot's shadow run verified the incumbent's calibration too, which the robot does not run on (it runs
    on the candidate's): a release made on the recalibrated file could never pass the pilot. Nor does it need the
    incumbent's calibration at all: its kept copy gone, the pilot still passes."""
    store, a, version, profile, plan = released_then_recalibrated(tmp_path, excited,
                                                                  ("sim", "bench", "pilot", "production"))
    profile.with_name(f"arm_profile.{version}.yaml").unlink()
    b = create_bundle("scripted", None, str(profile), None, note="B")
    store.add_bundle(b)
    for stage in ("sim", "bench", "pilot"):
        promote(store, b.id, CELL, stage)
        result = run_stage(store, plan[stage], CELL, stage)
        assert result.verdict == "pass"
    with open_record(result.folders[0]) as rec:
        assert rec.context["release"]["incumbent"] == a.id
        assert rec.context["embodiment"]["sha256"] == b.manifest["calibration"]["sha256"]


def test_a_calibration_gone_from_its_path_and_its_kept_copy_is_one_line_naming_both(tmp_path, excited):
    _, _, version, profile, _ = released_then_recalibrated(tmp_path, excited)
    kept = profile.with_name(f"arm_profile.{version}.yaml")
    profile.unlink()
    kept.unlink()
    result = cli("run", "--cell", CELL, "--stage", "sim", "--plan", str(tmp_path / "plan.yaml"),
                 "--site", str(tmp_path / "site"))
    assert result.exit_code == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and f"calibration {profile} changed since create" in lines[0]
    assert f"{profile}: no such calibration file" in lines[0] and f"{kept}: no such calibration file" in lines[0]
