"""``cellguard replay`` of a loose .mcap file: no default page beside it (another loose record's replay would replace
it), as ``report`` refuses; and the page names the record it replayed (id, start, file)."""

from __future__ import annotations

import shutil

import pytest
import yaml
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.record.reader import open_record

runner = CliRunner()


@pytest.fixture(scope="module")
def loose(tmp_path_factory):
    """Two short quadruped records, each copied out of its run folder into one folder: loose/a.mcap, loose/b.mcap."""
    root = tmp_path_factory.mktemp("loose")
    (root / "loose").mkdir()
    for name, seed in (("a", 3), ("b", 4)):
        scenario = root / f"{name}.yaml"
        scenario.write_text(yaml.safe_dump({"cell": "quadruped-turns", "seed": seed, "acceptance_cycles": 2,
                                            "production_cycles": 0}))
        result = runner.invoke(app, ["run", str(scenario), "--out", str(root / name)])
        assert result.exit_code == 0, result.output
        shutil.copyfile(root / name / "record.mcap", root / "loose" / f"{name}.mcap")
    return root / "loose"


def test_a_loose_mcap_needs_an_output_and_nothing_is_written(loose):
    before = sorted(p.name for p in loose.iterdir())
    result = runner.invoke(app, ["replay", str(loose / "a.mcap"), "--cycle", "1"])
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0] == (f"error: {loose / 'a.mcap'}: is a record file outside a run folder; "
                                            "name the page to write with -o FILE"), result.output
    assert sorted(p.name for p in loose.iterdir()) == before


def test_each_page_names_its_record(loose, tmp_path):
    pages = {}
    for name in ("a", "b"):
        pages[name] = tmp_path / f"{name}.html"
        result = runner.invoke(app, ["replay", str(loose / f"{name}.mcap"), "--cycle", "1", "-o", str(pages[name])])
        assert result.exit_code == 0, result.output
    for name, other in (("a", "b"), ("b", "a")):
        with open_record(loose / f"{name}.mcap") as rec, open_record(loose / f"{other}.mcap") as not_it:
            mine, theirs = (rec.record_id, rec.start_utc), (not_it.record_id, not_it.start_utc)
        page = pages[name].read_text()
        assert mine[0] and mine[0] != theirs[0]
        assert f"record <code>{mine[0]}</code>" in page and f"<b>{mine[1]}</b>" in page
        assert f"Record file <code>{(loose / f'{name}.mcap').absolute()}</code>" in page
        assert theirs[0] not in page
