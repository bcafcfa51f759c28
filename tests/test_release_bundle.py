"""Release bundles: same inputs, same id; a changed policy file is refused and moves nothing."""

from __future__ import annotations

import json
import os

import pytest
from release_helpers import CELL, cli, pointers, replay_file

from cellguard.release import create_bundle
from cellguard.release.bundle import release_id


def test_identical_inputs_give_the_same_id_and_any_change_a_new_one(tmp_path):
    a = create_bundle("scripted", None, CELL, None, note="v1")
    b = create_bundle("scripted", None, CELL, None, note="v1")
    assert a.id == b.id == release_id(a.manifest)
    assert create_bundle("scripted", None, CELL, None, note="v2").id != a.id
    guard = tmp_path / "guard.yaml"
    guard.write_text("watchdog_s: 0.2\n")
    c = create_bundle("scripted", None, CELL, guard, note="v1")
    assert c.id != a.id and c.manifest["envelope"]["watchdog_s"] == 0.2
    assert a.manifest["profile"]["calibration_version"] and a.manifest["policy"]["sha256"]


def test_create_twice_keeps_one_immutable_bundle(tmp_path):
    site = tmp_path / "site"
    first = json.loads(cli("create", "--policy", "scripted", "--profile", CELL, "--site", str(site), "--json").stdout)
    again = json.loads(cli("create", "--policy", "scripted", "--profile", CELL, "--site", str(site), "--json").stdout)
    assert first["id"] == again["id"] and first["new"] and not again["new"]


def test_a_policy_file_changed_since_create_is_one_line_exit_2_and_no_pointer_moves(tmp_path):
    site, policy = tmp_path / "site", replay_file(tmp_path / "policy.npz")
    made = cli("create", "--policy", f"replay:{policy}", "--profile", CELL, "--site", str(site), "--json")
    assert made.exit_code == 0, made.output
    rid = json.loads(made.stdout)["id"]
    replay_file(policy, offset=0.01)  # the weights change after the bundle was frozen
    result = cli("promote", rid, "--cell", CELL, "--to", "sim", "--site", str(site))
    assert result.exit_code == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "changed since create" in lines[0] and "Traceback" not in result.output
    assert pointers(site) == []


def test_an_unknown_envelope_key_is_one_line_exit_2(tmp_path):
    guard = tmp_path / "guard.yaml"
    guard.write_text("watchdog_seconds: 0.2\n")
    result = cli("create", "--policy", "scripted", "--profile", CELL, "--envelope", str(guard),
                 "--site", str(tmp_path / "site"))
    assert result.exit_code == 2 and "watchdog_seconds: unknown key" in result.stderr


@pytest.mark.parametrize(("text", "message"), [("watchdog_s: true", "valid number, got True"),
                                              ("watchdog_s: '0.5'", "valid number, got '0.5'"),
                                              ("watchdog_s: .nan", "nan is not a finite number"),
                                              ("watchdog_s: !!set {a}", "a YAML !!set is no scenario value")])
def test_an_envelope_value_of_the_wrong_type_is_refused_as_in_a_scenario(tmp_path, text, message):
    """The envelope was validated leniently: ``watchdog_s: true`` froze a 1 s watchdog into the release."""
    guard = tmp_path / "guard.yaml"
    guard.write_text(text + "\n")
    result = cli("create", "--policy", "scripted", "--profile", CELL, "--envelope", str(guard),
                 "--site", str(tmp_path / "site"))
    assert result.exit_code == 2 and "watchdog_s: " in result.stderr and message in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and not (tmp_path / "site").exists()


def test_a_profile_whose_robot_is_not_a_name_is_one_line_exit_2(tmp_path):
    profile = tmp_path / "profile.yaml"
    profile.write_text("robot: [1]\n")  # was a TypeError traceback (a list is not hashable)
    result = cli("create", "--policy", "scripted", "--profile", str(profile), "--site", str(tmp_path / "site"))
    assert result.exit_code == 2 and "robot [1] is not a registered cell" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("option, value, says", [("--map", "fifo", "is a FIFO, not a regular action map file"),
                                                 ("--map", "/dev/zero", "larger than the limit of 1048576 bytes"),
                                                 ("--policy", "onnx:fifo", "is a FIFO, not a regular file"),
                                                 ("--policy", "replay:/dev/zero", "is a character device")])
def test_a_fifo_or_device_as_the_map_or_policy_is_one_line_exit_2(tmp_path, option, value, says):
    """`--map FIFO` waited forever and `--map /dev/zero` filled the memory (read whole before any check)."""
    from test_fleet_outbox import run_with_fifo_guard

    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    value = value.replace("fifo", str(fifo))
    args = ["create", "--policy", f"onnx:{tmp_path / 'm.onnx'}", "--profile", CELL, "--site", str(tmp_path / "site"),
            option, value]  # a policy that takes a map (a later --policy replaces it)
    result = run_with_fifo_guard(fifo, lambda: cli(*args))
    assert result.exit_code == 2 and result.stderr.count("\n") == 1 and says in result.stderr, result.output
    assert not (tmp_path / "site").exists()


@pytest.mark.parametrize("policy", ["onnx:m.onnx?map=MAP", "onnx:m.onnx?ma%70=MAP", "onnx:m.onnx?dt=0.05&%6Dap=MAP",
                                    "lerobot:policy_dir?ma%70=MAP", "openpi:ws://127.0.0.1:1?map=MAP"])
def test_an_action_map_given_as_a_policy_option_however_encoded_is_one_line_exit_2(tmp_path, policy):
    """``?ma%70=FILE`` passed the check of the text ``map=``; the adapter decoded it to ``map`` and used the map
    unhashed (edited after create, it still promoted). openpi's ``?map=`` was not checked at all."""
    args = ["create", "--policy", policy.replace("MAP", str(tmp_path / "map.yaml")), "--profile", CELL,
            "--site", str(tmp_path / "site")]
    result = cli(*args)
    assert result.exit_code == 2 and result.stderr == "error: --policy: give the action map with --map, not ?map=\n", \
        result.output
    assert not (tmp_path / "site").exists()
