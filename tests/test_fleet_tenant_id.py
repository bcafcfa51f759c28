"""A tenant's role is named from its id, checked as every other reader of a tenant id checks it: an id past 40
characters made a role name past PostgreSQL's 63 bytes, which it cut short, so such a tenant was added yet could never
push (a signature refuses its id), and a second sharing its first 40 characters failed with a raw DuplicateObject."""

from __future__ import annotations

import re

import pytest
from hypothesis import given
from hypothesis import strategies as st

from cellguard.errors import ConfigError
from cellguard.fleet.signature import ID_PATTERN
from cellguard.fleet.store import FleetStore

pytest.importorskip("psycopg")

STORE = FleetStore("host=127.0.0.1 port=1 user=nobody dbname=postgres", "a" * 20)  # the longest store name; no server


@given(st.text(max_size=60))
def test_a_role_is_named_only_for_an_id_the_pattern_takes(tenant):
    if re.fullmatch(ID_PATTERN, tenant):
        role = STORE.tenant_role(tenant)
        assert role.endswith(f"_t_{tenant}") and len(role.encode()) <= 63
    else:
        with pytest.raises(ConfigError, match=r"^tenant: expected an opaque id matching"):
            STORE.tenant_role(tenant)


def test_ids_past_40_characters_are_refused_by_name_not_cut_short():
    stem = "t" * 40
    assert len(STORE.tenant_role(stem).encode()) == 63
    for long in (stem + "1", stem + "2"):
        with pytest.raises(ConfigError, match=re.escape(repr(long))):
            STORE.tenant_role(long)
