"""`release verify` hashes again the files each release a stage can run (current or last_good) froze: a policy file,
action map or calibration changed under the release in production passed it as "log whole", as only `promote` and
`run` re-hashed a release's inputs, and only the one they took. A release no stage can run is not checked: its files
may be gone."""

from __future__ import annotations

import copy
import hashlib
import importlib.util
import json

import pytest
from release_helpers import CELL, cli, log_pass, replay_file, to_production
from test_release_calibration import calibrated

from cellguard.release import Store, create_bundle, promote
from cellguard.release.errors import BundleMismatch

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
    assert doc["ok"] and doc["log_ok"] and doc["inputs"] == {
        "checked": sorted([old, new]), "changed": [], "unreadable": [], "upgraded": [], "not_checked": [],
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


def _made_elsewhere(store, monkeypatch, edit) -> str:
    """A release made and promoted to sim by another install (another cellguard version, or with an extra or a
    plugin this one lacks): a scripted release's manifest as ``edit`` changes it, promoted as that install did (its
    own inputs checked there, not here); its id."""
    from cellguard.release import promotion
    from cellguard.release.bundle import Bundle, release_id

    manifest = copy.deepcopy(create_bundle("scripted", None, CELL, None, "").manifest)
    edit(manifest)
    bundle = Bundle(release_id(manifest), manifest)
    store.add_bundle(bundle)
    with monkeypatch.context() as patched:
        patched.setattr(promotion, "verify_bundle", lambda *args, **kwargs: None)
        promote(store, bundle.id, bundle.cell, "sim")
    return bundle.id


def _problems(site, code: int) -> tuple[list[str], str, dict]:
    """``release verify``'s problem lines, its text and its JSON document, both asserted to exit ``code``."""
    text, doc = _verify(site, code)
    lines = [line.removeprefix("broken: ") for line in text.splitlines() if line.startswith("broken: ")]
    assert doc["problems"] == lines, text
    return lines, text, doc


def test_a_policy_whose_extra_is_not_installed_here_is_not_checked_not_broken(tmp_path, monkeypatch):
    if importlib.util.find_spec("lerobot") is not None:
        pytest.skip("LeRobot is installed here: its policy is checked")
    site, model = tmp_path / "site", tmp_path / "model"
    model.mkdir()
    (model / "config.json").write_text("{}")

    def lerobot(m):
        m["policy"] = {"spec": f"lerobot:{model}?dt=0.05", "sha256": "ab" * 32}

    rid = _made_elsewhere(Store(site), monkeypatch, lerobot)
    lines, text, doc = _problems(site, 0)
    assert lines == [] and doc["ok"] and "log whole: 1 entries, chain verified" in text
    said = [line for line in text.splitlines() if line.startswith(f"release {rid}: policy lerobot:")]
    assert len(said) == 1 and "not checked here (needs lerobot, not installed here" in said[0], text
    assert doc["inputs"]["not_checked"] == said and doc["inputs"]["checked"] == [rid]


def test_a_cell_whose_plugin_is_not_installed_here_is_not_checked_not_broken(tmp_path, monkeypatch):
    site = tmp_path / "site"

    def plugin_cell(m):
        m["profile"]["cell"] = "cell-of-a-plugin-gone"

    rid = _made_elsewhere(Store(site), monkeypatch, plugin_cell)
    lines, text, doc = _problems(site, 0)
    said = (f"release {rid}: profile of 'cell-of-a-plugin-gone' and policy scripted: not checked here (needs the "
            f"plugin of cell 'cell-of-a-plugin-gone': unknown cell 'cell-of-a-plugin-gone'")
    assert lines == [] and [line for line in text.splitlines() if line.startswith(said)], text
    assert doc["ok"] and doc["inputs"]["not_checked"][0].startswith(said)


def test_a_policy_file_gone_cannot_be_read_and_is_not_said_changed(tmp_path):
    site, policy = tmp_path / "site", replay_file(tmp_path / "policy.npz")
    store = Store(site)
    rid = _released(store, f"replay:{policy}")
    promote(store, rid, CELL, "sim")
    frozen = store.bundle(rid).manifest["policy"]["sha256"]
    policy.unlink()
    lines, text, doc = _problems(site, 1)
    assert lines == [f"release {rid}: policy replay:{policy} cannot be read (replay file {policy}: no such file; "
                     f"frozen sha256 {frozen[:12]})"], text
    assert "1 cannot be read;" in text and "changed since create" not in text
    assert doc["inputs"]["changed"] == [] and [c["sha256"] for c in doc["inputs"]["unreadable"]] == [None]


def _older(version: str, policy: str = "", profile: str = ""):
    """A manifest edit: made by cellguard ``version``, whose hash of the policy or profile was another."""

    def edit(m):
        m["cellguard"] = version
        m["policy"]["sha256"] = policy or m["policy"]["sha256"]
        m["profile"]["sha256"] = profile or m["profile"]["sha256"]
    return edit


@pytest.mark.parametrize("input_", ["policy scripted", f"profile of {CELL!r}"])
def test_a_hash_of_cellguards_own_code_after_an_upgrade_is_said_an_upgrade(tmp_path, monkeypatch, input_):
    from cellguard import __version__

    site, other = tmp_path / "site", "cd" * 32
    edit = _older("0.0.1", policy=other) if input_.startswith("policy") else _older("0.0.1", profile=other)
    rid = _made_elsewhere(Store(site), monkeypatch, edit)
    lines, text, doc = _problems(site, 1)  # still refused: promote and run take the hash now
    assert len(lines) == 1 and lines[0].startswith(f"release {rid}: {input_}: cellguard upgraded (0.0.1 -> "
                                                   f"{__version__}) since create: re-create the release"), text
    assert "changed since create" not in text and "1 made by another cellguard;" in text
    assert [c["input"] for c in doc["inputs"]["upgraded"]] == [input_.partition(" ")[0]]
    assert doc["inputs"]["changed"] == []
    with pytest.raises(BundleMismatch, match=r"cellguard upgraded \(0\.0\.1 -> "):  # promote says it the same way
        promote(Store(site), rid, CELL, "bench")


def test_a_hash_of_cellguards_own_code_changed_by_the_same_version_is_changed(tmp_path, monkeypatch):
    from cellguard import __version__

    site = tmp_path / "site"
    rid = _made_elsewhere(Store(site), monkeypatch, _older(__version__, policy="cd" * 32))
    lines, _, doc = _problems(site, 1)
    assert len(lines) == 1 and lines[0].startswith(f"release {rid}: policy scripted changed since create")
    assert len(doc["inputs"]["changed"]) == 1 and doc["inputs"]["upgraded"] == []


def test_a_policy_file_changed_across_an_upgrade_is_still_changed(tmp_path, monkeypatch):
    site, policy = tmp_path / "site", replay_file(tmp_path / "policy.npz")

    def replay(m):
        m["cellguard"] = "0.0.1"
        m["policy"] = {"spec": f"replay:{policy}", "sha256": "cd" * 32}  # a file's hash: not cellguard's code

    rid = _made_elsewhere(Store(site), monkeypatch, replay)
    lines, _, doc = _problems(site, 1)
    assert len(lines) == 1 and lines[0].startswith(f"release {rid}: policy replay:{policy} changed since create")


def test_the_chains_result_is_said_when_only_files_changed(tmp_path):
    site, policy = tmp_path / "site", replay_file(tmp_path / "policy.npz")
    store = Store(site)
    rid = _released(store, f"replay:{policy}")
    promote(store, rid, CELL, "sim")
    replay_file(policy, offset=0.01)
    lines, text, doc = _problems(site, 1)
    assert len(lines) == 1 and "log whole: 1 entries, chain verified; head " in text, text
    assert doc["log_ok"] and not doc["ok"]
