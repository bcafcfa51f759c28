"""A joint's friction and damping are identified only where it moved both ways. Moving one way, ``sign(qd)`` is a
constant: friction is then the intercept of torque against speed and damping its slope, both taking up whatever the
model misses that does not flip with the direction. A 1 s arm excitation (still fading in) moves shoulder_lift down
only: identify gave damping 0.382 [0.330, 0.435] (truth 0.5) and friction 0.220 [0.211, 0.230] (truth 0.2), and
``--write`` stored both."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from arm_excitation import ARM, arm_excitation, profile  # noqa: F401 (fixture)
from typer.testing import CliRunner

from cellguard.calibrate.identify import identify, load_segments, parse_params
from cellguard.calibrate.torque_model import MIN_SPEED
from cellguard.cli import app
from cellguard.robot.registry import make_cell

runner = CliRunner()
LIFT = "shoulder_lift"


@pytest.fixture(scope="module")
def one_way(tmp_path_factory):
    """1 s of the arm's excitation: shoulder_lift moves faster than MIN_SPEED downwards only."""
    return arm_excitation(tmp_path_factory, 1.0)


def speeds(segments, cell, joint: str) -> np.ndarray:
    i = cell.profile.joint_names.index(joint)
    return np.concatenate([s.qd[:-1, i] for s in segments])


def test_friction_and_damping_of_a_joint_moved_one_way_are_not_identifiable(one_way):
    cell = make_cell(ARM)
    segments = load_segments([one_way], cell)
    lift = speeds(segments, cell, LIFT)
    assert (lift > MIN_SPEED).sum() == 0 and (lift < -MIN_SPEED).sum() > 100  # down only, on enough ticks to fit
    result = identify(segments, cell, parse_params("friction,damping,armature", cell))
    by = {(e["parameter"], e["joint"]): e for e in result["estimates"]}
    assert by[("friction", LIFT)]["interval"] is None and by[("damping", LIFT)]["interval"] is None
    assert by[("friction", LIFT)]["note"] == "not identifiable from this data"
    assert by[("armature", LIFT)]["interval"] is not None  # its acceleration takes both signs
    assert any("damping, friction: not excited" in w for w in result["warnings"]), result["warnings"]


def test_a_joint_moved_both_ways_keeps_them(one_way):
    from cellguard.calibrate.identify import BOTH_WAYS_TICKS

    cell = make_cell(ARM)
    segments = load_segments([one_way], cell)
    result = identify(segments, cell, parse_params("friction,damping", cell))
    kept = 0
    for e in result["estimates"]:
        v = speeds(segments, cell, e["joint"])
        both = min((v > MIN_SPEED).sum(), (v < -MIN_SPEED).sum()) >= BOTH_WAYS_TICKS
        assert (e["interval"] is not None) == both, (e, (v > MIN_SPEED).sum(), (v < -MIN_SPEED).sum())
        kept += both
    assert kept >= 4  # elbow and wrist_flex at least: the rule is not "nothing from a short record"


def test_write_keeps_the_profile_s_values_for_them(one_way, profile):
    result = runner.invoke(app, ["identify", str(one_way), "--write", str(profile)])
    assert result.exit_code == 0, result.output
    measured = {(m["joint"], m["parameter"]): m for m in yaml.safe_load(profile.read_text())["measured"]}
    assert measured[(LIFT, "friction")]["value"] == "0.2 N*m"  # the profile's, as it was
    assert measured[(LIFT, "friction")]["measured"] == "2026-10-14"
    assert (LIFT, "damping") not in measured
    assert measured[("elbow", "friction")]["method"].startswith("sysid")  # the rest is written


def test_only_refits_them_not_either(one_way, profile):
    out = runner.invoke(app, ["identify", str(one_way), "--only", f"{LIFT},friction", "--only", f"{LIFT},damping",
                              "--only", "elbow,friction", "--json"])
    assert out.exit_code == 0, out.output
    by = {(e["parameter"], e["joint"]): e for e in json.loads(out.stdout)["estimates"]}
    assert by[("friction", LIFT)]["interval"] is None and by[("damping", LIFT)]["interval"] is None
    assert by[("friction", "elbow")]["interval"] is not None
    before = profile.read_bytes()
    refused = runner.invoke(app, ["identify", str(one_way), "--only", f"{LIFT},friction", "--write", str(profile)])
    assert refused.exit_code == 2 and "nothing identified to write" in refused.output, refused.output
    assert profile.read_bytes() == before


def test_each_way_needs_its_ticks():
    from cellguard.calibrate.identify import BOTH_WAYS_TICKS, moves_both_ways

    fast = 2 * MIN_SPEED
    qd = np.zeros((1000, 4))
    qd[:BOTH_WAYS_TICKS, 0], qd[BOTH_WAYS_TICKS:, 0] = fast, -fast  # enough each way
    qd[:BOTH_WAYS_TICKS - 1, 1], qd[BOTH_WAYS_TICKS:, 1] = fast, -fast  # one tick short one way
    qd[:BOTH_WAYS_TICKS, 2], qd[BOTH_WAYS_TICKS:, 2] = MIN_SPEED, -fast  # one way only at friction's dead band
    qd[:, 3] = np.linspace(-1.0, -fast, 1000)  # one way only
    assert moves_both_ways(qd).tolist() == [True, False, False, False]
