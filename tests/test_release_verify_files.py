"""`release verify` hashes again the files each release a stage can run (current or last_good) froze: a policy file,
action map or calibration changed under the release in production passed it as "log whole", as only `promote` and
`run` re-hashed a release's inputs, and only the one they took. A release no stage can run is not checked: its files
may be gone."""

from __future__ import annotations

import hashlib
import json

import pytest
from release_helpers import CELL, cli, log_pass, replay_file, to_production
from test_release_calibration import calibrated

from cellguard.release import Store, create_bundle, promote

JOINTS = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_flex", "wrist_roll", "gripper"]


def _released(store, policy: str, action_map=None, profile: str = CELL, note: str = "") -> str:
    """``policy`` frozen into a release kept in ``store``; its id."""
    bundle = create_bundle(policy, action_map, profile, None, note)
    store.add_bundle(bundle)
    return bundle.id


def _verify(site, code: int):
    """``release verify`` as text and as JSON, both asserted to exit ``code``: (text, document)."""
    text, as_json = cli("verify", "--site", str(site)), cli("verify", "--site", str(site), "--json")
    assert text.exit_code == code and as_json.exit_code == code, text.output
    return text.stdout, json.loads(as_json.stdout)


def _sha(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _named(site, rid: str, what: str, now: str, frozen: str, kind: str) -> None:
    """Verify fails with one problem line naming release ``rid``, the input ``what`` and both hashes, said in JSON
    as well."""
    text, doc = _verify(site, 1)
    lines = [line for line in text.splitlines() if line.startswith("broken: ")]
    assert len(lines) == 1, text
    assert f"release {rid}: {what}" in lines[0] and f"sha256 {now[:12]}" in lines[0], lines[0]
    assert f"{frozen[:12]}" in lines[0], lines[0]
    assert not doc["ok"] and doc["problems"] == [lines[0].removeprefix("broken: ")]
    changed = doc["inputs"]["changed"]
    assert [(c["release"], c["input"], c["sha256"], c["frozen"]) for c in changed] == [(rid, kind, now, frozen)]


def test_a_policy_file_changed_under_the_release_in_production_is_named(tmp_path):
    site, policy = tmp_path / "site", replay_file(tmp_path / "policy.npz")
    store = Store(site)
    rid = _released(store, f"replay:{policy}")
    to_production(store, rid)
    frozen = store.bundle(rid).manifest["policy"]["sha256"]
    replay_file(policy, offset=0.01)  # the weights swapped after the release went out
    _named(site, rid, f"policy replay:{policy} changed since create", _sha(policy), frozen, "policy")


def test_an_action_map_changed_under_a_current_release_is_named(tmp_path):
    pytest.importorskip("onnx")
    from hostile.test_tracebacks import small_onnx

    amap = tmp_path / "map.yaml"
    amap.write_text(f"robot: {CELL}\nactions:\n" + "".join(
        f"  - {{name: {j}, joint: {j}, unit: {'m' if j == 'gripper' else 'rad'}}}\n" for j in JOINTS))
    site, store = tmp_path / "site", Store(tmp_path / "site")
    rid = _released(store, f"onnx:{small_onnx(tmp_path / 'm.onnx')}?dt=0.05", amap)
    promote(store, rid, CELL, "sim")
    frozen = _sha(amap)
    amap.write_text(amap.read_text().replace("unit: rad", "unit: deg", 1))
    _named(site, rid, f"action map {amap.resolve()} changed since create", _sha(amap), frozen, "action map")


def test_a_calibration_changed_in_place_under_a_current_release_is_named(tmp_path):
    site, profile = tmp_path / "site", calibrated(tmp_path)
    store = Store(site)
    rid = _released(store, "scripted", profile=str(profile))
    promote(store, rid, CELL, "sim")
    frozen = _sha(profile)
    calibrated(tmp_path, elbow_friction="0.25 N*m")  # recalibrated in place, no copy of the old one kept
    _named(site, rid, f"calibration {profile.resolve()} changed since create", _sha(profile), frozen, "calibration")


def test_a_last_good_release_is_checked_and_an_untouched_site_is_whole(tmp_path):
    first, second = replay_file(tmp_path / "first.npz"), replay_file(tmp_path / "second.npz", offset=0.01)
    site = tmp_path / "site"
    store = Store(site)
    old = _released(store, f"replay:{first}")
    promote(store, old, CELL, "sim")
    log_pass(store, "sim", old)  # last_good at sim: a rollback there runs it
    new = _released(store, f"replay:{second}")
    promote(store, new, CELL, "sim")
    assert (store.pointers(CELL, "sim").current, store.pointers(CELL, "sim").last_good) == (new, old)
    text, doc = _verify(site, 0)
    assert "log whole" in text and "(2 checked: policy, action map, profile, calibration): whole;" in text
    assert doc["ok"] and doc["inputs"] == {"checked": sorted([old, new]), "changed": [], "not_checked": [],
                                           "idle_not_checked": 0}
    frozen = store.bundle(old).manifest["policy"]["sha256"]
    replay_file(first, offset=0.02)
    _named(site, old, f"policy replay:{first} changed since create", _sha(first), frozen, "policy")


def test_an_old_release_whose_file_was_removed_is_not_a_problem(tmp_path):
    first, second = replay_file(tmp_path / "first.npz"), replay_file(tmp_path / "second.npz", offset=0.01)
    site = tmp_path / "site"
    store = Store(site)
    for policy in (first, second):  # the first is then neither current nor last_good: nothing runs it
        promote(store, _released(store, f"replay:{policy}"), CELL, "sim")
    first.unlink()
    text, doc = _verify(site, 0)
    assert "log whole" in text and "neither current nor last_good: 1, not checked" in text, text
    assert doc["ok"] and len(doc["inputs"]["checked"]) == 1 and doc["inputs"]["idle_not_checked"] == 1


def test_a_served_policy_is_said_not_checked_and_its_server_not_contacted(tmp_path):
    pytest.importorskip("websockets")
    pytest.importorskip("msgpack")
    from hostile.wsserver import serve_bytes

    from cellguard.policy.wire import packb

    site, store = tmp_path / "site", Store(tmp_path / "site")
    with serve_bytes(packb({"action_names": JOINTS})) as uri:
        rid = _released(store, f"openpi:{uri}?timeout=1&dt=0.05")
        promote(store, rid, CELL, "sim")
    text, doc = _verify(site, 0)  # the server is gone: contacted, it would fail
    said = f"release {rid}: policy openpi:{uri}?timeout=1&dt=0.05: not checked offline (served policy)"
    assert said in text.splitlines() and doc["inputs"]["not_checked"] == [said]
