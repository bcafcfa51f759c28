"""The site's secret key: made once, owner-only, kept; signature ids depend on it. No server needed."""

from __future__ import annotations

import datetime as dt
import os
import stat

import pytest

from cellguard.errors import ConfigError
from cellguard.fleet.export import export_batch
from cellguard.fleet.policy import DataPolicy
from cellguard.fleet.push import push
from cellguard.fleet.signature import Signature
from cellguard.fleet.site_key import KEY_FILE, site_key

TODAY = dt.date(2026, 11, 23)


def sig() -> Signature:
    return Signature("t-a", "s-1", TODAY.isoformat(), "friction", 0.8, "arm5", "arm-pick-place",
                     {"current_rms.elbow": 6.0}, 7, 1, "pv-1", "cal-1", "0.1.0")


def test_the_key_is_made_once_owner_only_and_kept(tmp_path):
    key = site_key(tmp_path / "site")
    path = tmp_path / "site" / KEY_FILE
    assert len(key) == 32 and stat.S_IMODE(path.stat().st_mode) == 0o600
    assert site_key(tmp_path / "site") == key != site_key(tmp_path / "other")
    assert [p.name for p in (tmp_path / "site").iterdir()] == [KEY_FILE]  # no temporary file left beside it


def test_a_push_keys_its_ids_with_the_site_key(tmp_path):
    policy = DataPolicy("t-a", "s-1", withheld=("policy_version",), retention_days=36500)
    first = push([sig()], policy, tmp_path, None, today=TODAY)
    again = push([sig()], policy, tmp_path, None, today=TODAY)
    (row,) = first.batch.signatures
    assert row["signature_id"] == again.batch.signatures[0]["signature_id"]  # a re-push is the same row
    assert row["signature_id"] == sig().signature_id(site_key(tmp_path))
    assert row == export_batch([sig()], policy, TODAY, key=site_key(tmp_path)).signatures[0]


@pytest.mark.parametrize("case", ["malformed", "group-readable", "a-folder"])
def test_a_key_that_is_not_one_is_refused_in_one_line(tmp_path, case):
    path = tmp_path / KEY_FILE
    if case == "a-folder":
        path.mkdir()
    else:
        path.write_text("not a key\n" if case == "malformed" else "ab" * 32 + "\n")
        os.chmod(path, 0o600 if case == "malformed" else 0o644)
    with pytest.raises(ConfigError, match=f"site key {path}: ") as info:
        site_key(tmp_path)
    assert "\n" not in str(info.value)
    assert path.exists()  # never replaced: the ids the site sent depend on it
