"""A release frozen from a policy that states no step period is refused with what can be done: a new release.

Made before the period was required, such a release was refused naming it, but the line went on with the policy's
own `give ?dt=SECONDS`, which a frozen release cannot take; then with `release create --policy '...?dt=SECONDS'`
alone, which `create` refused for a missing --profile, and without the release's action map or envelope; then without
its note (another id), and after an in-place recalibration with the profile's path, which holds another calibration
now."""

from __future__ import annotations

import json
import shlex
import shutil

import pytest
from cli_util import one_error
from release_helpers import CELL, cli
from test_release_calibration import calibrated

from cellguard.embodiment.profile import kept_copy
from cellguard.release import Store, create_bundle
from cellguard.release.bundle import Bundle, policy_hash, release_id
from cellguard.release.errors import ReleaseError

JOINTS = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_flex", "wrist_roll", "gripper"]


def _frozen_without_dt(spec: str, action_map=None, profile: str = CELL, envelope=None,
                       note: str = "") -> tuple[Bundle, Bundle]:
    """The release ``create`` made of ``spec?dt=0.05``, and the same as an older cellguard froze it: without the
    ``?dt=``."""
    made = create_bundle(f"{spec}{'&' if '?' in spec else '?'}dt=0.05", action_map, profile, envelope, note)
    manifest = {**made.manifest, "policy": {**made.manifest["policy"], "spec": spec}}
    return made, Bundle(release_id(manifest), manifest)


def test_the_suggested_command_makes_the_release_again_with_its_map_profile_and_envelope(tmp_path):
    pytest.importorskip("onnx")
    from hostile.test_tracebacks import small_onnx

    model = small_onnx(tmp_path / "dp.onnx")
    amap = tmp_path / "map.yaml"
    amap.write_text(f"robot: {CELL}\nactions:\n" + "".join(
        f"  - {{name: {j}, joint: {j}, unit: {'m' if j == 'gripper' else 'rad'}}}\n" for j in JOINTS))
    guard = tmp_path / "guard.yaml"
    guard.write_text("watchdog_s: 0.5\ntool_speed_max: 1.0\n")
    made, old = _frozen_without_dt(f"onnx:{model}", amap, str(calibrated(tmp_path)), guard, "pick v1 'left'")
    site = tmp_path / "site"
    Store(site).add_bundle(old)
    line = one_error(cli("promote", old.id, "--cell", CELL, "--to", "sim", "--site", str(site)))
    assert f"release {old.id}: its policy" in line and "the step period is not stated" in line
    assert "give ?dt" not in line and line.count("create a new release") == 1
    assert "a frozen release cannot take ?dt=" in line
    command, _, notes = line.partition("cellguard release create ")[2].partition(" (SECONDS: ")
    args = shlex.split(command)
    assert args[:2] == ["--policy", f"onnx:{model}?dt=SECONDS"] and args[args.index("--note") + 1] == "pick v1 'left'"
    envelope = notes.partition("FILE: a YAML file holding this release's envelope, ")[2].removesuffix(")")
    assert json.loads(envelope) == {"watchdog_s": 0.5, "tool_speed_max": 1.0}
    (tmp_path / "envelope.yaml").write_text(envelope)
    args = [a.replace("SECONDS", "0.05") if a.startswith("onnx:") else a for a in args]
    args = [str(tmp_path / "envelope.yaml") if a == "FILE" else a for a in args]
    again = cli("create", *args, "--site", str(site), "--json")
    assert again.exit_code == 0, again.output
    assert json.loads(again.stdout)["id"] == made.id  # as it was made with ?dt=: the same release


def test_after_an_in_place_recalibration_the_suggested_command_takes_the_calibration_the_release_runs_on(tmp_path):
    """It named the profile's path, which `identify --write` rewrites: the release made had the new calibration."""
    pytest.importorskip("onnx")
    from hostile.test_tracebacks import small_onnx

    model = small_onnx(tmp_path / "dp.onnx")
    profile = calibrated(tmp_path)
    _, old = _frozen_without_dt(f"onnx:{model}", profile=str(profile))
    kept = kept_copy(profile, old.manifest["calibration"]["version"])
    shutil.copy(profile, kept)  # as `identify --write` keeps it, then rewrites the profile
    calibrated(tmp_path, elbow_friction="0.25 N*m")
    site = tmp_path / "site"
    Store(site).add_bundle(old)
    line = one_error(cli("promote", old.id, "--cell", CELL, "--to", "sim", "--site", str(site)))
    args = shlex.split(line.partition("cellguard release create ")[2].partition(" (SECONDS: ")[0])
    assert args[args.index("--profile") + 1] == str(kept) and "--note" not in args  # it had none
    again = cli("create", *[a.replace("SECONDS", "0.05") for a in args], "--site", str(site), "--json")
    assert again.exit_code == 0, again.output
    assert json.loads(again.stdout)["manifest"]["calibration"]["sha256"] == old.manifest["calibration"]["sha256"]


def test_promoting_an_onnx_release_without_a_period_says_to_create_a_new_one(tmp_path):
    pytest.importorskip("onnx")
    from hostile.test_tracebacks import small_onnx

    model = small_onnx(tmp_path / "dp.onnx")
    site = tmp_path / "site"
    _, old = _frozen_without_dt(f"onnx:{model}")
    Store(site).add_bundle(old)
    line = one_error(cli("promote", old.id, "--cell", CELL, "--to", "sim", "--site", str(site)))
    assert f"cellguard release create --policy 'onnx:{model}?dt=SECONDS' --profile {CELL} (SECONDS: " in line
    assert "--map" not in line and "--envelope" not in line  # the release had neither


def test_a_calibration_gone_is_said_beside_the_command(tmp_path):
    """Gone from its path and from the copy kept: the command names the path frozen and says no file holds it."""
    pytest.importorskip("onnx")
    from hostile.test_tracebacks import small_onnx

    profile = calibrated(tmp_path)
    _, old = _frozen_without_dt(f"onnx:{small_onnx(tmp_path / 'dp.onnx')}", profile=str(profile))
    profile.unlink()
    with pytest.raises(ReleaseError) as refused:
        policy_hash(old)
    said = str(refused.value)
    assert "the step period is not stated" in said and f"--profile {profile.resolve()} " in said
    assert f"calibration {profile.resolve()} changed since create and no copy of it is kept" in said


def test_a_frozen_spec_with_options_is_shown_with_dt_among_them():
    pytest.importorskip("websockets")
    pytest.importorskip("msgpack")
    from hostile.wsserver import serve_bytes

    from cellguard.policy.wire import packb

    with serve_bytes(packb({"action_names": JOINTS})) as uri:
        _, old = _frozen_without_dt(f"openpi:{uri}?timeout=1")
        with pytest.raises(ReleaseError) as refused:
            policy_hash(old)
    assert f"--policy 'openpi:{uri}?timeout=1&dt=SECONDS'" in str(refused.value)
    assert "give ?dt" not in str(refused.value) and "\n" not in str(refused.value)
