"""A release frozen from a policy that states no step period is refused with what can be done: a new release.

Made before the period was required, such a release was refused naming it, but the line went on with the policy's
own `give ?dt=SECONDS`, which a frozen release cannot take."""

from __future__ import annotations

import pytest
from cli_util import one_error
from release_helpers import CELL, cli

from cellguard.release import Store, create_bundle
from cellguard.release.bundle import Bundle, policy_hash, release_id
from cellguard.release.errors import ReleaseError

JOINTS = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_flex", "wrist_roll", "gripper"]


def _frozen_without_dt(spec: str) -> Bundle:
    """The release ``create`` made of ``spec?dt=0.05``, as an older cellguard froze it: without the ``?dt=``."""
    made = create_bundle(f"{spec}{'&' if '?' in spec else '?'}dt=0.05", None, CELL, None)
    manifest = {**made.manifest, "policy": {**made.manifest["policy"], "spec": spec}}
    return Bundle(release_id(manifest), manifest)


def test_promoting_an_onnx_release_without_a_period_says_to_create_a_new_one(tmp_path):
    pytest.importorskip("onnx")
    from hostile.test_tracebacks import small_onnx

    model = small_onnx(tmp_path / "dp.onnx")
    site = tmp_path / "site"
    old = _frozen_without_dt(f"onnx:{model}")
    Store(site).add_bundle(old)
    line = one_error(cli("promote", old.id, "--cell", CELL, "--to", "sim", "--site", str(site)))
    assert f"release {old.id}: its policy" in line and "the step period is not stated" in line
    assert "give ?dt" not in line
    assert f"create a new release whose policy gives it, e.g. release create --policy 'onnx:{model}?dt=SECONDS'" in line


def test_a_frozen_spec_with_options_is_shown_with_dt_among_them():
    pytest.importorskip("websockets")
    pytest.importorskip("msgpack")
    from hostile.wsserver import serve_bytes

    from cellguard.policy.wire import packb

    with serve_bytes(packb({"action_names": JOINTS})) as uri:
        old = _frozen_without_dt(f"openpi:{uri}?timeout=1")
        with pytest.raises(ReleaseError) as refused:
            policy_hash(old)
    assert f"--policy 'openpi:{uri}?timeout=1&dt=SECONDS'" in str(refused.value)
    assert "give ?dt" not in str(refused.value) and "\n" not in str(refused.value)
