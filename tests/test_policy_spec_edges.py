"""Edges of a ``policy:`` spec: ``scripted:`` (an empty argument) ran as ``scripted`` and a release took it for
another policy; openpi's ``retries=٣`` (non-ASCII digits) passed the checks and failed only on connecting."""

from __future__ import annotations

import socket
from urllib.parse import quote

import pytest
import yaml
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from release_helpers import CELL, cli
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import ConfigError
from cellguard.policy.registry import make_policy
from cellguard.robot.registry import make_cell

ARM = make_cell(CELL)


@settings(max_examples=100, deadline=None)
@given(st.text(min_size=1, max_size=20))
def test_scripted_takes_no_argument(arg):
    with pytest.raises(ConfigError, match=r"^policy: 'scripted' takes no argument, got "):
        make_policy(f"scripted:{arg}", ARM)


def test_a_release_of_scripted_colon_is_the_release_of_scripted(tmp_path):
    """It was stored as a second, "new" release of the same program; refused outright, a release an earlier version
    stored as ``scripted:`` could no longer run or be promoted."""
    from cellguard.release import Store

    site = tmp_path / "site"
    assert cli("create", "--policy", "scripted", "--profile", CELL, "--site", str(site)).exit_code == 0
    again = cli("create", "--policy", "scripted:", "--profile", CELL, "--site", str(site))
    assert again.exit_code == 0 and "(created)" not in again.output, again.output
    assert len(Store(site).bundle_ids()) == 1


def test_a_run_of_scripted_colon_runs_scripted(tmp_path):
    scenario = tmp_path / "s.yaml"
    scenario.write_text(yaml.safe_dump({"cell": CELL, "policy": "scripted:", "acceptance_cycles": 1,
                                           "production_cycles": 0}))
    result = CliRunner().invoke(app, ["run", str(scenario), "--out", str(tmp_path / "out")])
    assert result.exit_code == 0, result.output


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@settings(max_examples=150, deadline=None)
@given(st.text(st.characters(categories=["Nd"]), max_size=4) | st.text(max_size=6))
def test_retries_is_ascii_digits_in_range_before_connecting(retries):
    assume(not (retries.isascii() and retries.isdigit() and int(retries) <= 5))  # those connect
    with pytest.raises(ConfigError, match=r"^policy: openpi: option retries"):
        make_policy(f"openpi:ws://127.0.0.1:{_free_port()}?dt=0.02&retries={quote(retries, safe='')}", ARM)


def test_retries_with_thousands_of_leading_zeros_is_one_line():
    """``int()`` refuses a text of over 4300 digits: a traceback, where the value is 0 or out of range."""
    for retries, said in (("0" * 4301, None), ("0" * 4301 + "7", r"must be in \[0, 5\]")):
        spec = f"openpi:ws://127.0.0.1:{_free_port()}?dt=0.02&retries={retries}"
        with pytest.raises(ConfigError, match=said or "openpi"):
            make_policy(spec, ARM)  # 0 retries: no server there, refused when connecting


@pytest.mark.parametrize("retries", ["٣", "３", "1٠"])
def test_non_ascii_digits_are_named(retries):
    with pytest.raises(ConfigError, match=f"^policy: openpi: option retries='{retries}' is not an integer"):
        make_policy(f"openpi:ws://127.0.0.1:{_free_port()}?dt=0.02&retries={retries}", ARM)


@given(st.text(min_size=1, max_size=12).filter(lambda text: not text.isascii()))
def test_a_number_in_a_spec_is_ascii_digits_only(text):
    """Every number a spec or metadata gives as text (``?dt=``, ``?hz=``): ``float`` reads other scripts' digits
    (``٠.٠٢`` is 0.02), which no file of cellguard's writes and no other option took."""
    from cellguard.options import bounded_float

    with pytest.raises(ConfigError, match="ASCII digits"):
        bounded_float(text, "dt", 0.0, 1e9)
    assert bounded_float("0.02", "dt", 0.0, 1.0) == 0.02
