"""``record query`` names what the user wrote as it was written, on its command line: a refused statement in the
user's letter case (``pragma version`` was refused as "PRAGMA VERSION"; the statements themselves are in
test_record_query_refusal), and ``--timeout`` as given (0 was refused as "0.0 s", 0.1234567 stopped at "the time
limit of 0.123457 s")."""

from __future__ import annotations

import pytest
from cli_util import one_error
from record_synth import record
from typer.testing import CliRunner

from cellguard.cli import app

READ_ONLY = "; the query is read-only: one SELECT over the tables cycles and events"


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("query") / "run"
    record(folder, 2, 100)
    return folder


def test_pragma_is_refused_as_written_in_one_line(run_dir):
    result = CliRunner().invoke(app, ["record", "query", str(run_dir), "pragma version"])
    assert one_error(result) == f'error: sql: "pragma version" is refused{READ_ONLY}'


@pytest.mark.parametrize(("given", "said"), [("0", "0"), ("-1", "-1"), ("100000", "100000"), ("86400.5", "86400.5"),
                                             ("1e999", "inf"), ("nan", "nan")])
def test_a_timeout_out_of_range_is_named_as_given(run_dir, given, said):
    result = CliRunner().invoke(app, ["record", "query", str(run_dir), "SELECT 1", "--timeout", given])
    assert one_error(result) == f"error: --timeout: {said} s is outside (0, 86400]"


def test_the_time_limit_is_named_as_given(run_dir):
    result = CliRunner().invoke(app, ["record", "query", str(run_dir), "SELECT count(*) FROM range(1000000000000)",
                                      "--timeout", "0.1234567"])
    assert one_error(result) == "error: sql: stopped after the time limit of 0.1234567 s (--timeout)"
