"""identify on a `cellguard run` record and on terms the records do not excite. A run record decimated below the servo
rate keeps full-rate ticks only in windows around its events and failed cycles (contact, stops, recoveries), which the
fit's free-motion model does not describe: a pick-and-place run with recoveries wrote wrist_flex armature 0.04988
[0.04982, 0.04995] (truth 0.05) "95 % simultaneous". --write now refuses such a record in one line; without --write
the fit is reported with a warning. The not-excited warning names each joint's terms (it said "armature, damping,
friction" while --write stored those of four joints), and --only says it too (it said nothing)."""

from __future__ import annotations

import json

import pytest
from arm_excitation import ARM, arm_excitation, profile  # noqa: F401 (fixture)
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.embodiment import load_profile
from cellguard.robot.registry import make_cell
from cellguard.runtime.loop import run_scenario
from cellguard.scenario import Scenario

runner = CliRunner()
LIFT = "shoulder_lift"
WINDOWS = "keeps the servo rate only in windows around its events (contact, stops, recoveries)"


@pytest.fixture(scope="module")
def windowed(tmp_path_factory):
    """Two pick-and-place cycles recorded as a run records them (50 Hz), the second failed by a tool slip: its
    ticks kept at the servo rate (about 9,000, enough stretches of 200 to fit)."""
    out = tmp_path_factory.mktemp("run") / "run"
    scenario = Scenario(cell=ARM, acceptance_cycles=1, production_cycles=1,
                        faults=[{"kind": "tool_slip", "at_cycle": 1}])
    run_scenario(scenario, out)
    return out


@pytest.fixture(scope="module")
def one_way(tmp_path_factory):
    """1 s of the arm's excitation: shoulder_lift moves down only (its friction and damping are not excited)."""
    return arm_excitation(tmp_path_factory, 1.0)


@pytest.mark.parametrize("how", [[], ["--only", "elbow,friction"]])
def test_write_refuses_a_run_records_event_windows(windowed, profile, how):  # noqa: F811 (fixture)
    before = profile.read_bytes()
    result = runner.invoke(app, ["identify", str(windowed), *how, "--write", str(profile)])
    lines = result.output.strip().splitlines()
    assert result.exit_code == 2 and len(lines) == 1, result.output
    assert lines[0].startswith("error: --write: ") and WINDOWS in lines[0] and f"cellguard excite {ARM}" in lines[0]
    assert profile.read_bytes() == before and sorted(p.name for p in profile.parent.iterdir()) == [profile.name]


def test_without_write_the_fit_says_its_intervals_do_not_hold(windowed):
    result = runner.invoke(app, ["identify", str(windowed), "--json"])
    assert result.exit_code == 0, result.output
    said = [w for w in json.loads(result.output)["warnings"] if WINDOWS in w]
    assert len(said) == 1 and "do not hold" in said[0], said


def test_a_term_not_excited_is_named_by_joint_and_kept_by_write(one_way, profile):  # noqa: F811 (fixture)
    result = runner.invoke(app, ["identify", str(one_way), "--params", "friction,damping,armature", "--json"])
    assert result.exit_code == 0, result.output
    warnings = json.loads(result.output)["warnings"]
    assert any(f"{LIFT} damping, friction: not excited" in w and "--write keeps the profile's values" in w
               for w in warnings), warnings
    written = runner.invoke(app, ["identify", str(one_way), "--params", "friction,damping,armature",
                                  "--write", str(profile)])
    assert written.exit_code == 0, written.output
    assert f"{LIFT} damping, friction: not excited" in written.output
    measured = {(m.joint, m.parameter): m.method for m in load_profile(make_cell(ARM).model, profile).measured}
    assert not any(measured.get((LIFT, p), "").startswith("sysid") for p in ("friction", "damping")), measured
    assert measured[("elbow", "armature")].startswith("sysid")


def test_only_warns_the_same(one_way, profile):  # noqa: F811 (fixture)
    result = runner.invoke(app, ["identify", str(one_way), "--only", f"{LIFT},friction", "--json"])
    assert result.exit_code == 0, result.output
    out = json.loads(result.output)
    assert out["estimates"][0]["interval"] is None
    assert any(f"{LIFT} friction: not excited" in w for w in out["warnings"]), out["warnings"]
    written = runner.invoke(app, ["identify", str(one_way), "--only", f"{LIFT},friction", "--write", str(profile)])
    lines = written.output.strip().splitlines()
    assert written.exit_code == 2 and len(lines) == 1, written.output  # nothing to write, and why
    assert lines[0].startswith("error: --write: nothing identified") and f"{LIFT} friction not excited" in lines[0]


def test_a_decimated_rate_the_writer_keeps_every_tick_at_is_fitted_whole():
    """The writer keeps every tick of a 1 kHz arm from about 667 Hz up (``decimation_stride``); 900 Hz was refused."""
    from cellguard.calibrate.identify import event_windows
    from cellguard.robot.registry import make_cell

    cell = make_cell(ARM)
    assert event_windows("r", "id", {"record": {"decimated_hz": 900}}, cell) is None
    assert event_windows("r", "id", {"record": {"decimated_hz": 1000}}, cell) is None
    assert WINDOWS in event_windows("r", "id", {"record": {"decimated_hz": 50}}, cell)
