"""SQL that opens with a ``--`` comment starts with "-", so the command line reads it as an option. After ``--`` it
is SQL (``record query FOLDER -- SQL``); given bare, the one error line quotes it whole and says to give it after
``--`` (it said "No such option: -- a comment\\x0aselect 1", or only the part before an "=", or "- " of "- 1").
An unknown option that could be one is still named as before."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from record_synth import record

SCRIPT = [sys.executable, "-c", "from cellguard.entry import main; main()"]  # what the console script runs
AFTER_DASHES = "is read as an option (it starts with '-'); give an argument that starts with '-' after '--', every " \
               "option before that (`"


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("query") / "run"
    record(folder, 2, 100)
    return folder


def cellguard(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([*SCRIPT, *args], capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("sql", ["-- a comment\nSELECT 1 AS one", "--a comment\nSELECT 1 AS one",
                                 "--x\nSELECT 1 AS one WHERE 1=1", "- 1"])
def test_sql_starting_with_a_dash_is_one_line_quoting_it_whole_and_saying_to_give_it_after_dashes(run_dir, sql):
    done = cellguard("record", "query", str(run_dir), sql)
    assert (done.returncode, done.stdout) == (2, "")
    assert len(done.stderr.splitlines()) == 1
    assert done.stderr.startswith(f"error: {json.dumps(sql)} {AFTER_DASHES}"), done.stderr


def test_sql_starting_with_a_comment_after_dashes_is_run_with_its_options_before(run_dir):
    done = cellguard("record", "query", "--timeout", "30", str(run_dir), "--", "-- a comment\nSELECT 1 AS one")
    assert (done.returncode, done.stdout, done.stderr) == (0, '{"one": 1}\n', "")


@pytest.mark.parametrize(("option", "said"), [("--timout", "error: No such option: --timout (Possible options: "
                                                           "--timeout) (`"),
                                              ("-x", "error: No such option: -x (`")])
def test_an_unknown_option_that_could_be_one_is_named_as_before(run_dir, option, said):
    done = cellguard("record", "query", str(run_dir), "SELECT 1", option)
    assert done.returncode == 2 and done.stderr.startswith(said) and len(done.stderr.splitlines()) == 1, done.stderr


@pytest.mark.parametrize("typed", ["-my run", "-x y", "--x=1 comment\nselect 1"])
def test_an_argument_the_parser_cut_to_a_short_option_still_gets_the_hint(typed):
    """Cut after one letter (``-m``) or at "=" (``--x``), what was typed could be no option: it said "No such option:
    -m"."""
    done = cellguard("diagnose", typed)
    assert done.returncode == 2 and len(done.stderr.splitlines()) == 1
    assert done.stderr.startswith(f"error: {json.dumps(typed)} {AFTER_DASHES}"), done.stderr


def test_the_hint_quotes_the_argument_not_an_option_value_before_it(tmp_path):
    """``run --out "- out" "- x.yaml"``: "- out" is the value of --out, read as such; the argument read as an option
    is "- x.yaml" (the hint quoted "- out")."""
    done = cellguard("run", "--out", "- out", "- x.yaml")
    assert done.returncode == 2 and done.stderr.startswith(f'error: "- x.yaml" {AFTER_DASHES}'), done.stderr


def test_a_mistyped_option_with_a_value_is_still_named_by_the_parser():
    done = cellguard("record", "query", "R", "--timout=5", "select 1")
    assert done.returncode == 2
    assert done.stderr.startswith("error: No such option: --timout (Possible options: --timeout) (`"), done.stderr
