"""identify --only re-fits one drifted term from production cycles; an unwritable profile is left as it was."""

from __future__ import annotations

import errno
import json
import os

import pytest
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.embodiment import load_profile
from cellguard.record.writer import RecordConfig
from cellguard.robot.arm_cell import ASSETS
from cellguard.robot.registry import make_cell
from cellguard.runtime.loop import Run, run_scenario
from cellguard.scenario import Scenario

runner = CliRunner()


@pytest.fixture(scope="module")
def production(tmp_path_factory):
    """Two pick-and-place cycles at full rate with elbow friction x1.3 (what the residual monitor flagged)."""
    scenario = Scenario(cell="arm-pick-place", acceptance_cycles=2, production_cycles=0)
    run = Run(scenario)
    run.cell.set_friction_scale("elbow", 1.3)
    out = tmp_path_factory.mktemp("only") / "run"
    run_scenario(scenario, out, run=run, record=RecordConfig(decimated_hz=1e9 / run.cell.dt_ns))
    return out


def test_only_refits_the_drifted_term_from_production_cycles(production, tmp_path):
    plain = runner.invoke(app, ["identify", str(production), "--params", "friction", "--json"])
    assert plain.exit_code == 0
    assert any(e["interval"] is None for e in json.loads(plain.output)["estimates"])  # all at once: not enough motion
    result = runner.invoke(app, ["identify", str(production), "--only", "elbow,friction", "--json"])
    assert result.exit_code == 0, result.output
    (e,) = json.loads(result.output)["estimates"]
    assert (e["joint"], e["parameter"]) == ("elbow", "friction")
    assert e["value"] == pytest.approx(0.26, rel=0.05) and e["interval"][0] <= 0.26 <= e["interval"][1]
    profile = tmp_path / "arm_profile.yaml"
    profile.write_bytes((ASSETS / "arm_profile.yaml").read_bytes())
    written = runner.invoke(app, ["identify", str(production), "--only", "elbow,friction", "--write", str(profile)])
    assert written.exit_code == 0, written.output
    new = load_profile(make_cell("arm-pick-place").model, profile)
    measured = {(m.joint, m.parameter): m for m in new.measured}
    assert measured[("elbow", "friction")].value == pytest.approx(0.26, rel=0.05)
    assert measured[("shoulder_lift", "friction")].value == 0.2  # the others as they were
    assert "-cal-" in new.version


@pytest.mark.parametrize("only, words", [("elbow", "is not JOINT,PARAM"), ("knee,friction", "'knee' is not a joint"),
                                          ("elbow,kp", "'kp' cannot be re-fitted alone")])
def test_bad_only_is_one_line(production, only, words):
    result = runner.invoke(app, ["identify", str(production), "--only", only])
    assert result.exit_code == 2 and words in result.output and len(result.output.strip().splitlines()) == 1


def test_an_unwritable_profile_is_left_as_it_was(production, tmp_path, monkeypatch):
    profile = tmp_path / "arm_profile.yaml"
    profile.write_bytes((ASSETS / "arm_profile.yaml").read_bytes())
    before = profile.read_bytes()
    (tmp_path / "arm_profile.2026-11-01.yaml").mkdir()  # the old version cannot be kept: the write must not start
    result = runner.invoke(app, ["identify", str(production), "--only", "elbow,friction", "--write", str(profile)])
    assert result.exit_code == 2 and "previous profile" in result.output
    assert len(result.output.strip().splitlines()) == 1
    assert profile.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["arm_profile.2026-11-01.yaml", "arm_profile.yaml"]
    (tmp_path / "arm_profile.2026-11-01.yaml").rmdir()
    replace = os.replace

    def full(source, destination):  # the new profile cannot be written: its rename fails, as on a full disk
        if os.path.basename(destination) == profile.name:
            raise OSError(errno.ENOSPC, "No space left on device")
        return replace(source, destination)

    monkeypatch.setattr(os, "replace", full)
    result = runner.invoke(app, ["identify", str(production), "--only", "elbow,friction", "--write", str(profile)])
    assert result.exit_code == 2 and "any earlier file there is unchanged" in result.output
    assert profile.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["arm_profile.yaml"]  # the copies it made, taken out
