"""``record export``: an ``-o`` name whose suffix names the other format is refused before anything is read or written
(``-o t.parquet`` without ``--format parquet`` wrote CSV into it, and ``--format parquet -o t.csv`` Parquet), and an
unknown ``--rate`` is named as the option given (the reader's "rate:" named no option of the command)."""

from __future__ import annotations

import pyarrow.parquet as pq
import pytest
from cli_util import one_error
from run_copies import recorded, run  # noqa: F401 (fixtures)
from typer.testing import CliRunner

from cellguard.cli import app

runner = CliRunner()


def _export(run, *args):
    return runner.invoke(app, ["record", "export", str(run), "--cycle", "1", *map(str, args)])


@pytest.mark.parametrize(("name", "fmt", "named"), [("t.parquet", "csv", "parquet"), ("t.PQ", "csv", "parquet"),
                                                    ("t.csv", "parquet", "csv")])
def test_a_suffix_naming_the_other_format_is_refused_naming_both(run, tmp_path, name, fmt, named):
    target = tmp_path / name
    result = _export(run, "-o", target, "--format", fmt)
    suffix = target.suffix.lower()
    assert one_error(result) == (f"error: -o {target}: a {suffix} file is {named}, but --format is {fmt}; give "
                                 f"--format {named}, or a name ending in .{fmt}")
    assert not target.exists()


@pytest.mark.parametrize(("name", "fmt"), [("t.parquet", "parquet"), ("t.csv", "csv"), ("ticks", "csv"),
                                           ("t.txt", "parquet")])
def test_a_suffix_of_its_format_or_of_none_writes(run, tmp_path, name, fmt):
    target = tmp_path / name
    assert _export(run, "-o", target, "--format", fmt).exit_code == 0
    assert target.read_bytes().startswith(b"PAR1") == (fmt == "parquet")
    if fmt == "parquet":
        assert pq.read_table(target).num_rows > 0


def test_an_unknown_rate_names_the_option(run, tmp_path):
    result = _export(run, "-o", tmp_path / "t.csv", "--rate", "bogus")
    assert one_error(result) == "error: --rate: 'bogus' is not one of decimated, full, all"
    assert not (tmp_path / "t.csv").exists()
