"""A file cellguard reads back (a baseline, a pilot run's shadow.json, a release's stored manifest, a release log
entry) holding JSON nested 3000 deep is refused in one line as malformed, as a record's messages are: each was a
RecursionError traceback (json.loads recurses once per level)."""

from __future__ import annotations

import pytest

from cellguard.diagnose.baseline import Baseline
from cellguard.errors import RecordError
from cellguard.release import log
from cellguard.release.errors import ReleaseError
from cellguard.release.evidence import _shadow
from cellguard.release.store import _stored_bundle

DEEP = "[" * 3000 + "]" * 3000
SHALLOW_DEEP = '{"chunks": ' + "[" * 150 + "]" * 150 + "}"  # past json_values.MAX_DEPTH, inside Python's stack


def test_a_baseline_nested_too_deep_is_one_record_error(tmp_path):
    path = tmp_path / "baseline.json"
    path.write_text(DEEP)
    with pytest.raises(RecordError, match="cannot read the baseline"):
        Baseline.load(path)


@pytest.mark.parametrize("text", ['{"chunks": ' + DEEP + "}", SHALLOW_DEEP])
def test_a_shadow_file_nested_too_deep_is_not_a_shadow_record(tmp_path, text):
    path = tmp_path / "shadow.json"
    path.write_text(text)
    with pytest.raises(RecordError, match="not a shadow record"):
        _shadow(path)


def test_a_stored_manifest_nested_too_deep_is_named_as_edited():
    with pytest.raises(ReleaseError, match="not a JSON object"):
        _stored_bundle("r1", DEEP)


def test_a_log_entry_nested_too_deep_reads_as_no_object():
    assert log._body('{"a": ' + DEEP + "}") is None
    assert log._body('{"kind": "gates"}') == {"kind": "gates"}
