"""``release create`` builds the envelope's guard on the release's cell as every stage's run does: a box in
centimetres (55 m on a 0.67 m arm), a soft_margin or a box leaving out the home pose were frozen and promoted, and
then every run refused them (exit 2)."""

from __future__ import annotations

import json

import pytest
from release_helpers import CELL, cli


def _create(tmp_path, text: str, cell: str = CELL):
    guard = tmp_path / "guard.yaml"
    guard.write_text(text + "\n")
    return guard, cli("create", "--policy", "scripted", "--profile", cell, "--envelope", str(guard),
                      "--site", str(tmp_path / "site"), "--json")


@pytest.mark.parametrize(("text", "cell", "says"), [
    ("box: [[-45, -45, 0.5], [45, 45, 55]]", CELL,
     "guard.box: [[-45.0, -45.0, 0.5], [45.0, 45.0, 55.0]] m: z up to 55 m lies 54.24 m beyond where the tool "
     "of arm-pick-place gets"),
    ("soft_margin: 0.2", CELL, "guard.soft_margin: 0.2 puts the soft limits of elbow at [-1.5, 1.5] rad, leaving out "
     "its home pose 1.9 rad"),
    ("box: [[0.3, -0.3, 0.0], [0.6, 0.3, 0.5]]", CELL, "m leaves out the home pose's tool point"),
    ("box: [[-1, -1, 0], [1, 1, 1]]", "quadruped-turns", "guard.box: cell quadruped-turns has no tool model"),
])
def test_an_envelope_every_run_would_refuse_is_refused_at_create(tmp_path, text, cell, says):
    guard, result = _create(tmp_path, text, cell)
    assert result.exit_code == 2 and result.stderr.count("\n") == 1, result.output
    assert result.stderr.startswith(f"error: --envelope {guard}: ") and says in result.stderr, result.stderr
    assert "Traceback" not in result.output
    assert not (tmp_path / "site").exists()  # nothing created


def test_a_box_in_metres_around_home_is_frozen_as_written(tmp_path):
    _, result = _create(tmp_path, "box: [[-0.5, -0.5, 0.0], [0.5, 0.5, 0.6]]\nwatchdog_s: 0.5")
    assert result.exit_code == 0, result.output
    envelope = json.loads(result.stdout)["manifest"]["envelope"]
    assert envelope["box"] == [[-0.5, -0.5, 0.0], [0.5, 0.5, 0.6]] and envelope["watchdog_s"] == 0.5
