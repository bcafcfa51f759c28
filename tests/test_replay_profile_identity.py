"""``replay`` runs the model the record was made with, or says which it ran: the record's calibrated profile is
found where its run read it (the absolute file its context names, from any working folder; or, recalibrated
since, as the copy kept beside it), else taken from the profile document the record holds; a profile other than
the record's is used with one warning naming both; the JSON and the page name the profile, its sha256 and its
calibration. It used to take the cell's stock profile silently and call that "the calibrated model", and then,
replayed from another folder than the run's, could not find the calibration the scenario named relative to it."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from dataclasses import replace
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cellguard.calibrate import replay as replay_module
from cellguard.calibrate.excitation import excitation_scenario, excite
from cellguard.calibrate.identify import CalibrationError
from cellguard.calibrate.replay import load_cycle
from cellguard.calibrate.torque_model import JointTerms
from cellguard.cli import app
from cellguard.record.context import versions
from cellguard.record.reader import open_record
from cellguard.robot.arm_cell import ASSETS
from cellguard.robot.physics import Physics
from cellguard.robot.registry import make_cell
from cellguard.runtime.loop import run_scenario
from cellguard.scenario import Scenario

ARM = "arm-pick-place"
PROFILE = Path("cal/arm_profile.yaml")  # as the scenario names it: relative to where the run was started
runner = CliRunner()


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """A site folder: ``cal/`` with a profile calibrated by ``identify --write`` (elbow friction x1.5 found), and
    ``run/``, one cycle recorded with ``calibration: cal/arm_profile.yaml``."""
    base = tmp_path_factory.mktemp("identity") / "site"
    (base / "cal").mkdir(parents=True)
    excite(excitation_scenario(ARM, 3.0), base / "ex", physics=Physics(friction={"elbow": 1.5}))
    (base / PROFILE).write_bytes((ASSETS / "arm_profile.yaml").read_bytes())
    written = runner.invoke(app, ["identify", str(base / "ex"), "--params", "friction", "--write",
                                  str(base / PROFILE)])
    assert written.exit_code == 0, written.output
    here = Path.cwd()
    os.chdir(base)
    try:
        run_scenario(Scenario(cell=ARM, acceptance_cycles=1, production_cycles=0, calibration=PROFILE), base / "run")
    finally:
        os.chdir(here)
    return base


@pytest.fixture
def site(made, tmp_path, monkeypatch):
    """The site, the working folder as at the run (the record names its profile file absolute, so the site stays
    where it was made): a test may move or replace its profile; ``cal/`` is put back after it."""
    kept = shutil.copytree(made / "cal", tmp_path / "cal")
    monkeypatch.chdir(made)
    yield made
    shutil.rmtree(made / "cal", ignore_errors=True)
    shutil.copytree(kept, made / "cal")


def recorded(site: Path) -> dict:
    with open_record(site / "run") as rec:
        return rec.context["embodiment"]


def used(site: Path, profile: Path | None = None, model: str = "calibrated"):
    """The terms and the profile a replay of the record in ``site`` runs with."""
    from cellguard.calibrate.replay import model_terms  # new with the fix: the CLI tests still run without it

    return model_terms(load_cycle(site / "run", 0), make_cell(ARM), model, profile)


def replay_json(*args: str, record: str = "run"):
    result = runner.invoke(app, ["replay", record, "--cycle", "0", "-o", "page.html", "--json", *args])
    assert result.exit_code == 0, result.output
    return result, json.loads(result.stdout)


def test_the_record_replays_in_its_own_calibrated_profile(site):
    emb = recorded(site)
    assert emb["sha256"] != make_cell(ARM).profile.sha256  # a calibrated record, not the stock profile
    terms, p = used(site)
    assert (p.sha256, p.version, p.calibration, p.path) == (emb["sha256"], emb["version"],
                                                            emb["calibration"]["version"], str(PROFILE.resolve()))
    assert p.note is None and p.is_records
    elbow = list(make_cell(ARM).profile.joint_names).index("elbow")
    stock = JointTerms.of_profile(make_cell(ARM), make_cell(ARM).profile)
    assert terms.friction[elbow] == pytest.approx(0.3, rel=0.05) != stock.friction[elbow]


def test_recalibrated_since_the_kept_copy_of_the_records_profile_is_used(site):
    """A later identify --write replaced cal/arm_profile.yaml and kept the record's as NAME.VERSION.yaml."""
    version = recorded(site)["version"]
    kept = PROFILE.with_name(f"arm_profile.{version}.yaml")
    shutil.copyfile(PROFILE, kept)
    PROFILE.write_bytes(PROFILE.read_bytes() + b"# recalibrated\n")  # a newer calibration: other bytes
    _, p = used(site)
    assert p.path == str(kept.resolve()) and p.is_records and p.note is None


def test_the_record_names_its_profile_file_absolute_outside_the_calibration_stamp(site):
    with open_record(site / "run") as rec:
        context = rec.context
    assert context["embodiment"]["file"] == str((site / PROFILE).resolve())
    assert context["scenario"]["calibration"] == str(PROFILE)  # as typed: relative to the run's folder
    elsewhere = {**context, "embodiment": {**context["embodiment"], "file": "/elsewhere/arm_profile.yaml"}}
    assert versions(elsewhere)["calibration_version"] == versions(context)["calibration_version"]


def test_replayed_from_another_folder_the_records_calibration_is_found(site, tmp_path, monkeypatch):
    """The scenario says cal/arm_profile.yaml, relative to the run's folder: replayed from elsewhere that named
    no file, and the stock profile was used with a warning that the record's was not found."""
    emb = recorded(site)
    _, there = replay_json()
    monkeypatch.chdir(tmp_path)
    result, d = replay_json(record=str(site / "run"))
    assert result.stderr == "" and d["profile_note"] is None
    assert (d["profile"], d["profile_sha256"]) == (str((site / PROFILE).resolve()), emb["sha256"])
    assert d["mismatch"] == there["mismatch"]


def test_the_records_profile_file_gone_replays_the_records_own_document(site):
    """Its measured friction, damping and armature from the record's context; the payload from the calibrated
    MJCF still beside where the file was. The same replay as with the file, and no warning."""
    emb = recorded(site)
    _, with_file = replay_json()
    PROFILE.unlink()
    result, d = replay_json()
    assert result.stderr == "" and d["profile_note"] is None
    assert (d["profile"], d["profile_version"], d["profile_sha256"], d["calibration"]) == (
        "the record's own document", emb["version"], emb["sha256"], emb["calibration"]["version"])
    assert d["mismatch"]["cost"] == pytest.approx(with_file["mismatch"]["cost"], rel=1e-6)
    page = (site / "page.html").read_text()
    assert "the record&#x27;s own document" in page and "id=profile-note" not in page
    stock = replay_json("--profile", str(ASSETS / "arm_profile.yaml"))[1]["mismatch"]["cost"]
    assert abs(stock - d["mismatch"]["cost"]) > 1e3 * abs(d["mismatch"]["cost"] - with_file["mismatch"]["cost"])


def test_without_its_calibrated_mjcf_the_document_replays_with_one_warning_that_the_payload_is_missing(site):
    """The profile keeps no payload: it is in the calibrated MJCF, gone with the folder. Not a silent 0."""
    emb = recorded(site)
    shutil.rmtree(site / "cal")
    result, d = replay_json()
    assert (d["profile"], d["profile_sha256"]) == ("the record's own document", emb["sha256"])
    warning = result.stderr.splitlines()
    assert len(warning) == 1 and warning[0] == f"warning: {d['profile_note']}"
    mjcf = (site / "cal").resolve() / emb["calibration"]["mjcf"]
    assert warning[0].startswith("warning: the record's profile file was not found; its own document gave the "
                                 "measured terms, but the calibrated MJCF")
    assert f"cannot be read at {mjcf}: replayed without a payload" in warning[0]
    assert "id=profile-note" in (site / "page.html").read_text()


def test_the_records_file_without_its_calibrated_mjcf_replays_as_the_document_does(site):
    """Removing only the MJCF ended the replay (exit 2) while removing the profile file too replayed with a
    warning: the same missing payload is the same warning, whichever file is still there."""
    emb = recorded(site)
    mjcf = (site / "cal").resolve() / emb["calibration"]["mjcf"]
    mjcf.unlink()
    result, d = replay_json()
    assert result.exit_code == 0, result.output
    assert d["profile_sha256"] == emb["sha256"] and d["profile"] == str((site / PROFILE).resolve())
    warning = result.stderr.splitlines()
    assert len(warning) == 1 and warning[0] == f"warning: {d['profile_note']}"
    assert warning[0].startswith("warning: the record's profile file was found, but the calibrated MJCF")
    assert f"cannot be read at {mjcf}: replayed without a payload" in warning[0]


def test_a_record_document_of_another_robot_is_one_calibration_error_not_terms_dropped(site):
    """Its measured joints are not the model's: every term was dropped and the replay called "the record's"."""
    shutil.rmtree(site / "cal")
    rc = load_cycle(site / "run", 0)
    doc = rc.profile["profile"]
    other = {**doc, "robot": "another-arm",
             "measured": [{**m, "joint": f"{m['joint']}_2"} for m in doc["measured"]]}
    with pytest.raises(CalibrationError, match="it is a profile of robot 'another-arm'"):
        replay_module.model_terms(replace(rc, profile={**rc.profile, "profile": other}), make_cell(ARM),
                                  "calibrated", None)
    renamed = {**doc, "measured": [{**m, "joint": f"{m['joint']}_2"} for m in doc["measured"]]}
    with pytest.raises(CalibrationError, match="it measured joints the arm-pick-place model lacks: elbow_2"):
        replay_module.model_terms(replace(rc, profile={**rc.profile, "profile": renamed}), make_cell(ARM),
                                  "calibrated", None)


def test_a_record_document_that_is_not_the_records_profile_is_one_calibration_error(site):
    shutil.rmtree(site / "cal")
    rc = load_cycle(site / "run", 0)
    forged = {**rc.profile, "profile": {**rc.profile["profile"], "sha256": "0" * 64}}
    with pytest.raises(CalibrationError, match=r"^the record's profile document \(context embodiment.profile\) "
                                               r"cannot be read: its sha256 0+ is not the record's"):
        replay_module.model_terms(replace(rc, profile=forged), make_cell(ARM), "calibrated", None)


def test_an_older_record_without_its_profile_replays_the_cells_own_and_says_so(site, monkeypatch):
    """A record from before its context held the profile's document and file: only the scenario's path."""
    load = replay_module.load_cycle

    def older(path, cycle):
        rc = load(path, cycle)
        return replace(rc, profile={k: v for k, v in rc.profile.items() if k not in ("profile", "file")})

    monkeypatch.setattr(replay_module, "load_cycle", older)
    shutil.rmtree(site / "cal")
    emb = recorded(site)
    result, d = replay_json()
    stock = make_cell(ARM).profile
    assert (d["profile_version"], d["profile_sha256"], d["calibration"]) == (stock.version, stock.sha256, None)
    assert d["record_profile_sha256"] == emb["sha256"]
    warning = result.stderr.splitlines()
    assert len(warning) == 1 and warning[0] == f"warning: {d['profile_note']}"
    assert f"made with profile {emb['version']} (calibration {emb['calibration']['version']}, sha256 " \
           f"{emb['sha256'][:12]}), not found at {PROFILE.resolve()}" in warning[0]
    assert f"replaying with the cell's own profile {stock.version}" in warning[0]
    page = (site / "page.html").read_text()
    assert "id=profile-note" in page and stock.sha256 in page and emb["sha256"] in page


def test_a_profile_other_than_the_records_is_used_with_one_warning_naming_both(site):
    other = site / "newer.yaml"
    other.write_bytes((ASSETS / "arm_profile.yaml").read_bytes())
    emb = recorded(site)
    result, d = replay_json("--profile", str(other))
    sha = hashlib.sha256(other.read_bytes()).hexdigest()
    assert (d["profile"], d["profile_sha256"]) == (str(other), sha)
    warning = result.stderr.splitlines()
    assert len(warning) == 1 and emb["sha256"][:12] in warning[0] and sha[:12] in warning[0], result.stderr
    summary = runner.invoke(app, ["replay", "run", "--cycle", "0", "-o", "page.html", "--profile", str(other)])
    assert summary.exit_code == 0 and f"from {other}, not the record's: " in summary.stdout, summary.output


def test_by_default_the_cli_replays_what_the_records_own_profile_given_does(site):
    """No --profile is the record's own profile given, and neither warns (the stock profile replays otherwise)."""
    emb = recorded(site)
    _, default = replay_json()
    result, d = replay_json("--profile", str(PROFILE))
    assert default["mismatch"] == d["mismatch"]
    assert result.stderr == "" and d["profile_note"] is None and default["profile_note"] is None
    assert (d["profile_version"], d["profile_sha256"], d["calibration"]) == (emb["version"], emb["sha256"],
                                                                            emb["calibration"]["version"])
    page = (site / "page.html").read_text()
    assert "id=profile-note" not in page and emb["sha256"] in page and emb["version"] in page


def test_the_nominal_model_names_no_profile(site):
    _, p = used(site, model="nominal")
    assert (p.version, p.sha256, p.calibration, p.note) == (None, None, None, None)
    assert p.recorded == recorded(site)["sha256"]


def test_a_site_folder_copied_whole_replays_from_its_own_profile_file(site, tmp_path, monkeypatch):
    """The absolute file is gone (the site moved); the scenario's path from the copied site's folder is the same
    bytes: the record's own file, with its MJCF and payload, no warning (the document lost the payload)."""
    moved = Path(shutil.copytree(site, tmp_path / "moved", ignore=shutil.ignore_patterns("*.html")))
    shutil.rmtree(site / "cal")
    monkeypatch.chdir(moved)
    result, d = replay_json()
    assert d["profile"] == str((moved / PROFILE).resolve()) and d["profile_note"] is None
    assert result.stderr == ""


def test_a_calibrated_mjcf_refused_for_its_payload_says_why_in_the_note(site):
    """A record's calibrated MJCF edited to a 25 kg payload (the arm's bound is 19.4 kg) was read and refused, and the
    note said only "cannot be read": the refusal's own words are in it now."""
    import mujoco

    mjcf = (site / "cal").resolve() / recorded(site)["calibration"]["mjcf"]
    spec = mujoco.MjSpec.from_file(str(mjcf))
    spec.body("tool").add_body(name="calibrated_payload").add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE,
                                                                    size=[1e-3, 0, 0], mass=25.0)
    mjcf.write_text(spec.to_xml())
    result, d = replay_json()
    assert f"cannot be read at {mjcf} (" in d["profile_note"] and "mass 25 kg is outside the plausible (0, 19.4] kg" \
        in d["profile_note"] and d["profile_note"].endswith(": replayed without a payload (name the profile with "
                                                            "--profile)"), d["profile_note"]
