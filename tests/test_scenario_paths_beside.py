"""A file a scenario names by a relative path is the one beside the scenario, from whatever folder it runs: from the
working folder, one scenario ran another calibrated profile (``calibration: cal/arm_profile.yaml`` took
``./cal/arm_profile.yaml``) or another policy file when started from another folder."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from cellguard.options import split_options
from cellguard.policy.registry import make_policy
from cellguard.robot.registry import make_cell
from cellguard.scenario import files_beside, load_scenario, parse_scenario
from release_helpers import replay_file

FOLDER = Path("/site/cellA")
NAME = st.text(st.characters(codec="ascii", categories=["L", "N"], include_characters="-_. "), min_size=1,
               max_size=20).filter(lambda n: n.strip(" ") == n and n not in (".", ".."))


def _scenario(tmp_path: Path, body: str) -> Path:
    (tmp_path / "cellA").mkdir(exist_ok=True)
    path = tmp_path / "cellA" / "s.yaml"
    path.write_text("cell: arm-pick-place\nacceptance_cycles: 1\nproduction_cycles: 0\n" + body)
    return path


def test_a_relative_calibration_is_the_one_beside_the_scenario_from_any_folder(tmp_path, monkeypatch):
    path = _scenario(tmp_path, "calibration: cal/arm_profile.yaml\n")
    for here in (tmp_path, path.parent):
        monkeypatch.chdir(here)
        assert load_scenario(path.relative_to(here)).calibration == path.parent / "cal" / "arm_profile.yaml"


def test_an_absolute_calibration_stays_as_written(tmp_path):
    path = _scenario(tmp_path, f"calibration: {tmp_path / 'elsewhere.yaml'}\n")
    assert load_scenario(path).calibration == tmp_path / "elsewhere.yaml"


def test_a_relative_policy_file_is_the_one_beside_the_scenario(tmp_path, monkeypatch):
    """Two folders each with a ``prog.npz`` of other poses: the scenario's own is replayed, run from the other."""
    path = _scenario(tmp_path, "policy: replay:prog.npz\n")
    replay_file(path.parent / "prog.npz")
    replay_file(tmp_path / "prog.npz", offset=0.01)
    monkeypatch.chdir(tmp_path)
    policy = make_policy(load_scenario(path.relative_to(tmp_path)).policy, make_cell("arm-pick-place"))
    assert policy.path == path.parent / "prog.npz"
    assert np.array_equal(policy.actions, np.load(path.parent / "prog.npz")["actions"])


def test_an_action_map_and_a_bridges_units_map_are_beside_it_too(tmp_path):
    path = _scenario(tmp_path, "policy: onnx:m/p.onnx?map=maps/a.yaml&dt=0.02\n"
                               "robot: lerobot:so101_follower?port=/dev/ttyACM0&units=u.yaml&id=arm 1\n")
    scenario = load_scenario(path)
    target, options = split_options(scenario.policy.partition(":")[2], None, "policy", "")
    assert (target, options) == (str(path.parent / "m" / "p.onnx"), {"map": str(path.parent / "maps" / "a.yaml"),
                                                                      "dt": "0.02"})
    target, options = split_options(scenario.robot.partition(":")[2], None, "robot", "")
    assert (target, options) == ("so101_follower", {"port": "/dev/ttyACM0", "units": str(path.parent / "u.yaml"),
                                                    "id": "arm 1"})


@given(NAME, NAME, st.sampled_from(["", "&dt=0.02", "&task=a%20b%26c%3Dd", "&task=pick+up&dt=0.1"]))
def test_a_policy_spec_keeps_every_option_and_takes_its_files_from_the_folder(model, amap, more):
    spec = f"onnx:{model}?map={amap}{more}"
    scenario = files_beside(parse_scenario({"cell": "arm-pick-place", "policy": spec}), FOLDER)
    target, options = split_options(scenario.policy.partition(":")[2], None, "policy", "")
    _, written = split_options(spec.partition(":")[2], None, "policy", "")
    assert target == str(FOLDER / model) and options == {**written, "map": str(FOLDER / amap)}


@given(NAME)
def test_what_names_no_file_is_left_as_written(name):
    spec = {"cell": "arm-pick-place", "policy": f"openpi:ws://{name}:8000", "robot": f"sim-server:udp://{name}:9"}
    scenario = files_beside(parse_scenario(spec), FOLDER)
    assert (scenario.policy, scenario.robot, scenario.calibration) == (spec["policy"], spec["robot"], None)
