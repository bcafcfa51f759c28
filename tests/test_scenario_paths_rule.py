"""One rule for the files a scenario names: relative to the scenario file's real location, normalised to the real file.

Made absolute beside the scenario but not normalised, ``calibration: ../run1/../cal.yaml`` was recorded as written
(``..`` and all, naming a path through a run's folder), and a linked scenario took its files beside the link while
``identify --write`` and ``replay`` resolved links to their targets.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from cellguard.errors import ScenarioError
from cellguard.options import split_options
from cellguard.scenario import files_beside, load_scenario, parse_scenario

HEAD = "cell: arm-pick-place\nacceptance_cycles: 1\nproduction_cycles: 0\n"


def _site(tmp_path: Path, body: str) -> Path:
    """``site/cellA/s.yaml`` holding ``body``, beside ``site/cellA/cal/``, and ``site/run1/``."""
    for folder in ("site/cellA/cal", "site/run1"):
        (tmp_path / folder).mkdir(parents=True, exist_ok=True)
    path = tmp_path / "site" / "cellA" / "s.yaml"
    path.write_text(HEAD + body)
    return path


def test_dot_dot_is_normalised_so_the_record_names_the_real_file(tmp_path):
    path = _site(tmp_path, "calibration: ../run1/../cellA/./cal/p.yaml\npolicy: replay:../run1/prog.npz\n")
    scenario = load_scenario(path)
    assert scenario.calibration == tmp_path / "site" / "cellA" / "cal" / "p.yaml"
    assert scenario.policy == f"replay:{tmp_path / 'site' / 'run1' / 'prog.npz'}"


def test_a_linked_scenario_takes_its_files_beside_its_target(tmp_path):
    path = _site(tmp_path, "calibration: cal/p.yaml\npolicy: onnx:m.onnx?map=maps/a.yaml&dt=0.02\n"
                           "robot: lerobot:so101_follower?port=/dev/ttyACM0&units=u.yaml\n")
    (tmp_path / "elsewhere").mkdir()
    link = tmp_path / "elsewhere" / "s.yaml"
    link.symlink_to(path)
    scenario, real = load_scenario(link), path.parent
    assert scenario.calibration == real / "cal" / "p.yaml"
    target, options = split_options(scenario.policy.partition(":")[2], None, "policy", "")
    assert (target, options["map"]) == (str(real / "m.onnx"), str(real / "maps" / "a.yaml"))
    assert split_options(scenario.robot.partition(":")[2], None, "robot", "")[1]["units"] == str(real / "u.yaml")


def test_a_link_on_the_way_is_followed_before_dot_dot(tmp_path):
    """``cal`` a link to ``/shared/profiles``: ``cal/../p.yaml`` is ``/shared/p.yaml`` to the system, as here (taken
    apart as text, it read ``cellA/p.yaml``: another file)."""
    path = _site(tmp_path, "calibration: linked/../p.yaml\n")
    (tmp_path / "shared" / "profiles").mkdir(parents=True)
    (path.parent / "linked").symlink_to(tmp_path / "shared" / "profiles")
    assert load_scenario(path).calibration == tmp_path / "shared" / "p.yaml"


def test_an_absolute_path_is_normalised_too(tmp_path):
    path = _site(tmp_path, f"calibration: {tmp_path}/site/run1/../cellA/cal/p.yaml\n")
    assert load_scenario(path).calibration == tmp_path / "site" / "cellA" / "cal" / "p.yaml"


@pytest.mark.parametrize(("body", "key"), [("calibration: \"a\\0b\"\n", None),
                                           ("robot: lerobot:so101_follower?units=a%00b\n", "robot option units"),
                                           ("policy: onnx:m.onnx?map=%00&dt=0.02\n", "policy option map")])
def test_a_nul_in_a_file_name_is_one_line_naming_the_file_and_the_key(tmp_path, body, key):
    path = _site(tmp_path, body)
    with pytest.raises(ScenarioError) as refused:
        load_scenario(path)
    said = str(refused.value)
    assert said.startswith(f"{path}: ") and "\n" not in said and (key is None or f": {key}: " in said), said


SEGMENT = st.sampled_from(["a", "b", "c d", ".", "..", "link"])


def _stays_inside(segments: list[str]) -> bool:
    """``folder/segments`` never climbs above the test's root (two levels up; the link's target is as deep)."""
    depth = 2
    for segment in segments:
        depth += {"..": -1, ".": 0}.get(segment, 1)
        if depth < 0:
            return False
    return True


@given(st.lists(SEGMENT, max_size=8).filter(_stays_inside))
def test_a_relative_path_names_the_file_the_system_opens(tmp_path_factory, segments):
    """Whatever the mix of names, ``.``, ``..`` and a link, the path taken is the file that opening the written path
    from the scenario's folder reaches, with no ``.`` or ``..`` left in it."""
    root = tmp_path_factory.getbasetemp() / "rule"
    folder = root / "site" / "cellA"
    if not folder.exists():
        (root / "target" / "deeper").mkdir(parents=True)
        folder.mkdir(parents=True)
        (folder / "link").symlink_to(root / "target" / "deeper")
    name = "/".join([*segments, "p.yaml"])
    os.makedirs(os.path.dirname(folder / name), exist_ok=True)
    (folder / name).write_text("written through the path as given\n")
    taken = files_beside(parse_scenario({"cell": "arm-pick-place", "calibration": name}), folder).calibration
    assert taken.is_absolute() and not {".", ".."} & set(taken.parts) and taken.is_relative_to(root)
    assert os.path.samefile(taken, folder / name)


def test_a_missing_folder_on_the_way_is_not_resolved_away(tmp_path):
    """``gone/../cal/p.yaml`` is no file the system opens (``gone`` is missing): resolved, it named ``cal/p.yaml``
    and a mistyped folder went unnoticed. It stays as written, and reading it fails naming it."""
    path = _site(tmp_path, "calibration: gone/../cal/p.yaml\n")
    (tmp_path / "site" / "cellA" / "cal" / "p.yaml").write_text("robot: arm\n")
    scenario = load_scenario(path)
    assert scenario.calibration == tmp_path / "site" / "cellA" / "gone" / ".." / "cal" / "p.yaml"
    assert not os.path.exists(scenario.calibration)
