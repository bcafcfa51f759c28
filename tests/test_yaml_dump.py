"""``dump_yaml`` writes what ``parse_yaml`` reads back equal: PyYAML's ``safe_dump`` follows YAML 1.1, which left a
text like ``09``, ``0o17`` or ``1e3`` plain, and the loader (YAML 1.2's numbers) read it back as a number."""

from __future__ import annotations

from hypothesis import example, given
from hypothesis import strategies as st

from cellguard.yaml_file import dump_yaml, parse_yaml

# texts that look like numbers, dates and times, where the two rule sets differ, beside any text at all
_LOOKALIKE = st.from_regex(r"[-+]?[0-9._:]{0,4}(?:[eE][-+]?[0-9]{1,3}|0[ox][0-9a-fA-F_]{1,4}|-[0-9]{2}-[0-9]{2})?",
                           fullmatch=True)
_SCALARS = st.one_of(st.none(), st.booleans(), st.integers(), st.floats(allow_nan=False), st.text(), _LOOKALIKE)
_VALUES = st.recursive(_SCALARS, lambda inner: st.lists(inner, max_size=4), max_leaves=12)


@given(st.dictionaries(st.one_of(st.text(), _LOOKALIKE), _VALUES, max_size=6))
@example({"previous": "09", "\x85": ["a\x85b", "-.5", "1_", "2026-11-01"]})  # NEL: PyYAML read it back as a space
def test_what_dump_yaml_writes_reads_back_equal(document):
    assert parse_yaml(dump_yaml(document), "test") == document


def test_a_text_the_loader_reads_as_a_number_is_quoted():
    assert dump_yaml({"previous": "09", "version": "0o17"}) == "previous: '09'\nversion: '0o17'\n"
