"""An explicit ``!!bool`` or ``!!set`` on a value it cannot be is one line naming the value, not a traceback:
``!!bool abc`` raised PyYAML's KeyError, ``!!set [1]`` a TypeError in the duplicate-key check."""

from __future__ import annotations

import pytest

from cellguard.errors import ConfigError
from cellguard.yaml_file import parse_yaml


@pytest.mark.parametrize(("text", "message"), [("!!bool abc", "line 1: !!bool 'abc' is not true or false"),
                                               ("!!bool ''", "line 1: !!bool '' is not true or false"),
                                               ("!!set [1]", "not valid YAML at line 1 (expected a mapping node")])
def test_a_bool_or_set_tag_on_another_value_is_one_line(text, message):
    with pytest.raises(ConfigError) as refused:
        parse_yaml(f"v: {text}\n", "test")
    assert str(refused.value).startswith(f"test: {message}") and "\n" not in str(refused.value)


@pytest.mark.parametrize(("text", "read"), [("!!bool Yes", True), ("!!bool off", False), ("!!set {a: null}", {"a"})])
def test_a_bool_or_set_tag_on_its_own_values_reads_them(text, read):
    assert parse_yaml(f"v: {text}\n", "test")["v"] == read
