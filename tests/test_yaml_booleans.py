"""Only YAML 1.2's booleans are booleans: ``true`` and ``false`` (``True``, ``TRUE``, ``False``, ``FALSE``).

PyYAML's YAML 1.1 resolver read ``yes``, ``no``, ``on`` and ``off`` (any of three cases) as booleans: ``site: no`` was
False, a joint named ``on`` the key True, and a field that wants text refused them with a puzzling message. A field
that wants a boolean and is written ``yes`` says to write true or false; ``dump_yaml`` still quotes what a YAML 1.1
reader would take for a boolean.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from hypothesis import example, given
from hypothesis import strategies as st

from cellguard.errors import ScenarioError
from cellguard.scenario import load_scenario, parse_scenario
from cellguard.yaml_file import dump_yaml, parse_yaml, yaml_bool_text

ROOT = Path(__file__).parents[1]
YAML_11_ONLY = ("yes", "no", "on", "off", "y", "n")
CORE = {"true": True, "True": True, "TRUE": True, "false": False, "False": False, "FALSE": False}


def _any_case(words) -> st.SearchStrategy[str]:
    return st.sampled_from(words).flatmap(
        lambda w: st.tuples(*(st.sampled_from([c.lower(), c.upper()]) for c in w)).map("".join))


@given(_any_case(YAML_11_ONLY))
@example("No")
@example("OFF")
def test_a_yaml_11_boolean_word_is_text_as_a_value_and_as_a_key(word):
    assert parse_yaml(f"{word}: {word}\nlist: [{word}]\n", "test") == {word: word, "list": [word]}


@given(_any_case(("true", "false")))
def test_only_the_three_spellings_of_true_and_false_are_booleans(word):
    assert parse_yaml(f"v: {word}\n", "test")["v"] == CORE.get(word, word)


def test_a_scenarios_text_fields_keep_the_words():
    scenario = parse_scenario(parse_yaml("cell: arm-pick-place\nsite: no\ncell_id: off\n", "s.yaml"))
    assert (scenario.site, scenario.cell_id) == ("no", "off")


@pytest.mark.parametrize("word", ["yes", "No", "on", "OFF", "y", '"true"'])
def test_a_boolean_field_written_as_a_word_says_to_write_true_or_false(word):
    """pydantic's lax mode would take "yes" and "on" for true: the scenario is validated strictly, as every other
    field is (a string is never taken for a number), so the one way to write a boolean is true or false."""
    raw = parse_yaml(f"cell: arm-pick-place\nresidual_monitor: {word}\n", "s.yaml")
    with pytest.raises(ScenarioError, match=r"^s\.yaml: residual_monitor: Input should be a valid boolean, got '.*': "
                                            r"text to YAML 1\.2; write true or false, unquoted$"):
        parse_scenario(raw, origin="s.yaml")


@given(st.dictionaries(_any_case(YAML_11_ONLY + ("true", "false")) | st.text(max_size=4),
                       _any_case(YAML_11_ONLY + ("true", "false")) | st.booleans() | st.text(max_size=4), max_size=6))
@example({"y": "n", "on": "yes", "name": "no", "flag": True})
def test_dump_yaml_quotes_what_yaml_11_reads_as_a_boolean(document):
    """Read back equal by the loader and by a YAML 1.1 reader (PyYAML's own, which reads ``yes``; ``y`` is quoted for
    the YAML 1.1 readers that take it for true)."""
    text = dump_yaml(document)
    assert parse_yaml(text, "test") == document and yaml.safe_load(text) == document
    for key, value in document.items():
        for word in (key, value):
            if yaml_bool_text(word):
                assert f"'{word}'" in text


def _yaml_files() -> list[Path]:
    return [p for folder in ("scenarios", "src", "tests") for p in (ROOT / folder).rglob("*.y*ml")
            if "node_modules" not in p.parts]


def _texts(value):
    if isinstance(value, dict):
        for key, item in value.items():
            yield from _texts(key)
            yield from _texts(item)
    elif isinstance(value, list):
        for item in value:
            yield from _texts(item)
    elif isinstance(value, str):
        yield value


@pytest.mark.parametrize("path", _yaml_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_yaml_file_in_the_repo_reads_as_before(path):
    """No text in it is a word YAML 1.1 read as a boolean: each file reads as it did."""
    assert not [t for t in _texts(parse_yaml(path.read_bytes(), str(path))) if yaml_bool_text(t)]


@pytest.mark.parametrize("path", sorted((ROOT / "scenarios").glob("*.yaml")), ids=lambda p: p.name)
def test_the_shipped_scenarios_still_load(path):
    load_scenario(path)
