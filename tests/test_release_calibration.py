"""A release binds a calibration of its cell's profile (``identify --write``): the release id covers its hash,
every stage's run takes it, and a calibration changed since ``release create`` is refused as a policy file is."""

from __future__ import annotations

import json

import pytest
from release_helpers import CELL, cli, pointers, write_plan

from cellguard.record.reader import open_record
from cellguard.release import Store, create_bundle, load_plan, promote, run_stage
from cellguard.release.errors import BundleMismatch
from cellguard.robot.arm_cell import ASSETS

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
