"""A record cut short (a run killed mid-way) that holds too few cycles to diagnose: the error says the record is
truncated and how to get a finished copy, as `record info` does; it said only "baseline: needs at least 5
acceptance cycles, got 2", the record's state hidden."""

from __future__ import annotations

import shutil

import pytest
from cli_util import one_error, record_run
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.record.reader import open_record

RUN = {"cell": "arm-pick-place", "seed": 3, "acceptance_cycles": 5, "production_cycles": 1}


@pytest.fixture(scope="module")
def cut(tmp_path_factory):
    """The run's record cut after its second cycle's end, as a killed run and writer leave it."""
    root = tmp_path_factory.mktemp("cut")
    whole = record_run(root, RUN)
    with open_record(whole) as rec:
        second_end = [c for c in rec.cycles()][1].t_end_ns
        refs = sorted(rec.layout.chunks, key=lambda ref: ref.offset)
        zero = refs[0].start_ns  # chunks are stamped on the record's clock, cycles from the run's start
        cut_at = next(ref.offset for ref in refs if ref.start_ns - zero > second_end + 1_000_000_000)
    folder = root / "cut"
    folder.mkdir()
    data = (whole / "record.mcap").read_bytes()[:cut_at]
    (folder / "record.mcap").write_bytes(data)
    shutil.copytree(whole / "index", folder / "index")  # an index written as the cycles ended, as a run's is
    return folder


@pytest.mark.parametrize("command", [["diagnose"], ["report", "-o", "page.html"]])
def test_too_few_cycles_in_a_cut_record_says_it_is_truncated_and_how_to_recover(cut, command, tmp_path,
                                                                                monkeypatch):
    monkeypatch.chdir(tmp_path)
    line = one_error(CliRunner().invoke(app, [command[0], str(cut), *command[1:]]))
    assert "acceptance cycles" in line, line
    assert "(the record is truncated" in line and f"cellguard record recover {cut} -o NEW_DIR" in line, line


def test_a_whole_record_with_too_few_cycles_says_only_that(tmp_path):
    whole = record_run(tmp_path, {**RUN, "acceptance_cycles": 2})
    line = one_error(CliRunner().invoke(app, ["diagnose", str(whole)]))
    assert "acceptance cycles" in line and "the record is" not in line, line
