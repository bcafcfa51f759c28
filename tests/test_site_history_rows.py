"""A sibling run's ``fixes.json`` as the advice reads it: a row cellguard did not write is skipped, never a
traceback, never a fleet line, never an impossible count."""

from __future__ import annotations

import json

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from cellguard.diagnose.cause import Finding
from cellguard.diagnose.recovery import advice, advice_lines
from cellguard.diagnose.site_history import save_fixes, site_history, site_rows

SITE = "plant-1"
GOOD = {"cause": "servo", "cycle": 14, "recovery": "rehome", "tried": 3, "fixed": 2}
FINDINGS = [Finding("servo", 14, 0.9, ("gain dropped",))]


def _history(tmp_path, body: str) -> list[dict]:
    """The history of run ``a`` with one sibling ``b`` whose fixes.json is ``body``."""
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    (tmp_path / "b/fixes.json").write_text(body)
    return site_history(tmp_path / "a", SITE)


@pytest.mark.parametrize("row", [
    {**GOOD, "scope": "fleet"},  # no customers: a KeyError in the advice
    {**GOOD, "scope": "fleet", "customers": 40},  # a site file speaking for the fleet's k customers
    {**GOOD, "scope": ["x"]},  # unhashable
    {**GOOD, "fixed": 10**400},  # OverflowError in the success rate
    {**GOOD, "tried": -3, "fixed": 90},  # "90 of -3 cycles"
    {**GOOD, "fixed": 4},  # fixed more than it tried
    {**GOOD, "tried": True, "fixed": False},
    {**GOOD, "tried": 2**63, "fixed": 0},
], ids=["fleet-no-customers", "fleet-customers", "scope-list", "huge", "negative", "over", "bools", "2**63"])
def test_a_row_cellguard_does_not_write_is_skipped_and_the_written_one_beside_it_kept(tmp_path, row):
    history = _history(tmp_path, json.dumps({"record_id": "b", "site": SITE, "fixes": [row, GOOD]}))
    assert [(r["cause"], r["recovery"], r["tried"], r["fixed"], r["record"]) for r in history] == [
        ("servo", "rehome", 3, 2, "b")]
    assert advice_lines(advice(FINDINGS, history))["servo", 14] == \
        "seen before at this site: rehome fixed it in 2 of 3 cycles (1 record(s))"


@pytest.mark.parametrize("body", [
    json.dumps({"record_id": ["a"], "site": SITE, "fixes": [GOOD]}),  # unhashable record
    "[" * 100_000 + "]" * 100_000,  # deeper than json reads: RecursionError
    "{not json",
], ids=["record-id-list", "nested", "not-json"])
def test_a_sibling_file_that_is_not_cellguards_is_skipped_whole(tmp_path, body):
    assert _history(tmp_path, body) == []


def test_a_site_row_claiming_the_fleet_is_advised_as_this_sites():
    """Rows with a ``record`` are this site's records: their ``scope`` does not make them the fleet store's."""
    row = {"cause": "servo", "recovery": "rehome", "tried": 3, "fixed": 2, "scope": "fleet", "customers": 40,
           "record": "b"}
    (advised,) = advice(FINDINGS, [row])
    assert [r["scope"] for r in advised["recoveries"]] == ["site"]
    assert "fleet" not in advice_lines([advised])["servo", 14]


def test_what_save_fixes_writes_is_read_back(tmp_path):
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
    save_fixes(tmp_path / "b", {"record_id": None, "site": SITE}, [GOOD, {**GOOD, "recovery": "back_off",
                                                                          "tried": 0, "fixed": 0}])
    assert [(r["recovery"], r["tried"], r["fixed"], r["record"]) for r in site_history(tmp_path / "a", SITE)] == [
        ("rehome", 3, 2, "b"), ("back_off", 0, 0, "b")]


JSON = st.recursive(st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=8),
                    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
                    max_leaves=12)
COUNT = st.integers(0, 20) | st.integers() | st.integers(min_value=2**62, max_value=2**64) | st.booleans()
KEYS = st.sampled_from(["cause", "recovery", "tried", "fixed", "scope", "customers", "cycle", "record"])
CHANGED = st.builds(lambda changes, gone: {k: v for k, v in {**GOOD, **changes}.items() if k not in gone},
                    st.dictionaries(KEYS, COUNT | st.sampled_from(["site", "fleet"]) | JSON, max_size=2),
                    st.sets(KEYS, max_size=1))  # a row cellguard writes with a field or two changed or left out
BODY = JSON | st.fixed_dictionaries({"site": st.just(SITE) | JSON, "fixes": st.lists(CHANGED | JSON, max_size=5)},
                                    optional={"record_id": st.none() | st.text(max_size=8) | JSON})


@settings(max_examples=400, deadline=None)
@given(BODY)
@example({"site": SITE, "fixes": [{**GOOD, "fixed": 10**400}]})
@example({"site": SITE, "record_id": ["a"], "fixes": [GOOD]})
def test_any_json_value_gives_rows_cellguard_could_have_written_or_none(body):
    rows = site_rows(body, SITE, "b")
    fixes = body.get("fixes") if isinstance(body, dict) else None
    assert len(rows) <= (len(fixes) if isinstance(fixes, list) else 0)
    for r in rows:
        assert set(r) == {"cause", "recovery", "tried", "fixed", "record"} and isinstance(r["record"], str)
        assert isinstance(r["cause"], str) and isinstance(r["recovery"], str)
        assert type(r["tried"]) is int and type(r["fixed"]) is int and 0 <= r["fixed"] <= r["tried"] < 2**63
    advised = advice([Finding(r["cause"], 1, 0.9, ()) for r in rows], rows)
    assert all(r["scope"] == "site" for a in advised for r in a["recoveries"])
    assert not any("in the fleet" in line for line in advice_lines(advised).values())


@given(st.lists(st.fixed_dictionaries({
    "cause": st.text(), "cycle": st.integers(0, 10**6), "recovery": st.text(),
    "tried": st.integers(0, 2**63 - 1), "fixed": st.integers(0, 2**63 - 1)}).map(
        lambda r: {**r, "fixed": min(r["fixed"], r["tried"])}), max_size=5), st.text(max_size=8) | st.none())
def test_every_row_cellguard_writes_is_read_back(fixes, record_id):
    rows = site_rows(json.loads(json.dumps({"record_id": record_id, "site": SITE, "fixes": fixes})), SITE, "b")
    assert rows == [{"cause": r["cause"], "recovery": r["recovery"], "tried": r["tried"], "fixed": r["fixed"],
                     "record": record_id or "b"} for r in fixes]
