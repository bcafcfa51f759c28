"""``record recover -o NEW_DIR`` writes only into a new or empty folder: into one that held another run's index
and files, it deleted that run's index parts and mixed its own record in with the rest."""

from __future__ import annotations

import shutil

from cli_util import one_error
from run_copies import recorded, run  # noqa: F401 (fixtures)
from test_record_outputs import digests
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.record.reader import open_record

runner = CliRunner()


def test_a_folder_holding_another_runs_index_is_refused_and_left_as_it_is(run, tmp_path):
    target = tmp_path / "T"
    shutil.copytree(run / "index", target / "index")
    shutil.copy(run / "summary.json", target)
    (target / "notes.txt").write_text("notes\n")
    before = digests(target)
    line = one_error(runner.invoke(app, ["record", "recover", str(run), "-o", str(target)]))
    assert line == f"error: -o {target}: exists and is not empty; give a new folder"
    assert digests(target) == before and sorted(p.name for p in target.iterdir()) == ["index", "notes.txt",
                                                                                       "summary.json"]


def test_an_empty_folder_receives_the_copy_and_nothing_else(run, tmp_path):
    (tmp_path / "T").mkdir()
    result = runner.invoke(app, ["record", "recover", str(run), "-o", str(tmp_path / "T")])
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in (tmp_path / "T").iterdir()) == ["index", "record.mcap"]
    with open_record(tmp_path / "T") as rec:
        assert rec.health().ok and [c.cycle for c in rec.cycles()] == list(range(6))
