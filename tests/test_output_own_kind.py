"""An output at a path the user gives replaces only a file of its own kind that cellguard wrote, or an empty file:
``release report -o`` wrote its page over the release's own frozen policy (exit 0; the release could never run
again), over a site's release plan and over a calibrated profile. Refused: one line naming the file, exit 2, the
file untouched."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from cli_util import one_error
from hypothesis import given, settings
from hypothesis import strategies as st
from release_helpers import CELL, cli, replay_file
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import RecordError
from cellguard.policy.onnx_export import save_mlp_onnx, trajectory_mlp
from cellguard.record.export import OWN_KINDS
from cellguard.record.outputs import refuse_output
from cellguard.robot.arm_cell import ASSETS
from cellguard.runtime.loop import run_scenario
from cellguard.scenario import Scenario

runner = CliRunner()
PAGE_HEAD = b"<!doctype html><html lang=en><head><meta charset=utf-8><title>cellguard "  # as every page has begun
REFUSED = "exists and is not {what} cellguard wrote; cellguard replaces only its own (or an empty file): choose " \
          "another path, or remove the file first"


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def refused(result, path: Path, what: str = "an HTML page", hint: str = "") -> None:
    assert one_error(result) == f"error: -o {path}: " + REFUSED.format(what=what) + hint


def record(folder: Path) -> Path:
    """A run folder of the arm cell: the fewest acceptance cycles a report reads."""
    run_scenario(Scenario(cell=CELL, acceptance_cycles=5, production_cycles=1), folder)
    return folder


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    return record(tmp_path_factory.mktemp("own_kind") / "run")


@pytest.fixture(scope="module")
def release(tmp_path_factory) -> tuple[Path, str, Path]:
    """(site, id, its frozen policy file): a replay release of the arm, as the probe made it."""
    base = tmp_path_factory.mktemp("own_kind_release")
    policy = replay_file(base / "p.npz")
    created = cli("create", "--policy", f"replay:{policy}", "--profile", CELL, "--site", str(base / "site"), "--json")
    assert created.exit_code == 0, created.output
    return base / "site", json.loads(created.stdout)["id"], policy


def test_release_report_keeps_the_release_policy_and_the_plan(release, tmp_path):
    site, rid, policy = release
    plan = tmp_path / "release-plan.yaml"
    plan.write_text("stages: {}\n")
    for kept in (policy, plan):
        before = digest(kept)
        refused(cli("report", rid, "-o", str(kept), "--site", str(site)), kept)
        assert digest(kept) == before


def test_report_keeps_a_calibrated_profile(run, tmp_path):
    profile = tmp_path / "arm_profile.yaml"
    profile.write_bytes((ASSETS / "arm_profile.yaml").read_bytes())
    refused(runner.invoke(app, ["report", str(run), "-o", str(profile)]), profile)
    assert profile.read_bytes() == (ASSETS / "arm_profile.yaml").read_bytes()


def test_a_page_of_any_command_and_an_empty_file_are_replaced(run, release, tmp_path):
    """Every page cellguard renders (report, release, replay) begins with ``PAGE_HEAD``: each replaces the other's."""
    site, rid, _ = release
    page, empty = tmp_path / "page.html", tmp_path / "empty.html"
    empty.touch()
    writes = [["report", str(run), "-o", str(page)], ["release", "report", rid, "-o", str(page), "--site", str(site)],
              ["replay", str(run), "--cycle", "0", "-o", str(page)], ["report", str(run), "-o", str(page)],
              ["report", str(run), "-o", str(empty)]]
    heads = set()
    for args in writes:
        result = runner.invoke(app, args)
        assert result.exit_code == 0, result.output
        out = Path(args[args.index("-o") + 1])
        assert out.read_bytes().startswith(PAGE_HEAD)
        heads.add(out.read_bytes()[:len(PAGE_HEAD) + 8])
    assert len(heads) == 3  # report, release and replay pages, each replaced by another


def test_report_to_its_default_path_named_is_accepted(run):
    """``-o RUN/report.html`` is the file ``report RUN`` writes: it was refused as "in the run folder"."""
    named = runner.invoke(app, ["report", str(run), "-o", str(run / "report.html")])
    assert named.exit_code == 0, named.output
    assert (run / "report.html").read_bytes().startswith(PAGE_HEAD)
    line = one_error(runner.invoke(app, ["report", str(run), "-o", str(run / "other.html")]))
    assert "is in the run folder" in line


def test_the_default_report_keeps_a_file_of_another_kind(tmp_path):
    run = record(tmp_path / "run")
    (run / "report.html").write_text("the technician's notes\n")
    result = runner.invoke(app, ["report", str(run)])
    assert one_error(result).startswith(f"error: -o {run / 'report.html'}: exists and is not an HTML page")
    assert (run / "report.html").read_text() == "the technician's notes\n"


@pytest.mark.parametrize("fmt, name, what", [("csv", "t.csv", "a CSV ticks export"),
                                             ("parquet", "t.parquet", "a Parquet ticks export")])
def test_export_replaces_only_its_own_export(run, tmp_path, fmt, name, what):
    out = tmp_path / name
    for _ in range(2):  # an earlier export is replaced
        result = runner.invoke(app, ["record", "export", str(run), "--format", fmt, "-o", str(out)])
        assert result.exit_code == 0, result.output
    foreign = tmp_path / f"foreign{out.suffix}"
    if fmt == "csv":
        foreign.write_text("part,dx_mm\nA,1.5\n")
    else:  # a Parquet file with the export's very columns, not written by cellguard
        pq.write_table(pq.read_table(out).replace_schema_metadata(None), foreign)
    before = digest(foreign)
    refused(runner.invoke(app, ["record", "export", str(run), "--format", fmt, "-o", str(foreign)]), foreign, what,
            OWN_KINDS[fmt].hint)
    assert digest(foreign) == before


def test_export_keeps_the_policy_file(run, release):
    _, _, policy = release
    before = digest(policy)
    csv = policy.with_suffix(".csv")
    csv.write_bytes(policy.read_bytes())  # the same bytes under an export's name
    refused(runner.invoke(app, ["record", "export", str(run), "-o", str(csv)]), csv, "a CSV ticks export")
    assert digest(policy) == before


def test_train_demo_policy_overwrite_replaces_only_a_cellguard_model(release, tmp_path):
    _, _, policy = release
    before = digest(policy)
    line = one_error(runner.invoke(app, ["train-demo-policy", "-o", str(policy), "--overwrite", "--cycles", "2"]))
    assert line == f"error: -o {policy}: " + REFUSED.format(what="an ONNX model")
    assert digest(policy) == before
    from cellguard.cli.policy import _cellguard_onnx

    model = save_mlp_onnx(trajectory_mlp(np.array([0.0, 1.0]), np.zeros((2, 6)), 2, 0.05), tmp_path / "m.onnx", {})
    with open(model, "rb") as f:
        assert _cellguard_onnx(f)  # a model cellguard saved is what --overwrite replaces


@settings(max_examples=80, deadline=None)
@given(st.tuples(st.integers(0, len(PAGE_HEAD)), st.binary(max_size=100)).map(lambda c: PAGE_HEAD[:c[0]] + c[1]))
def test_a_page_replaces_only_a_page_or_nothing(tmp_path_factory, data):
    """Whatever a file holds, a page replaces it only if it is empty or begins as cellguard's pages do."""
    from cellguard.record.outputs import PAGE

    out = tmp_path_factory.mktemp("any") / "out.html"
    out.write_bytes(data)
    if not data or data.startswith(PAGE_HEAD):
        refuse_output(out, None, kind=PAGE)
    else:
        with pytest.raises(RecordError, match=r"is not an HTML page cellguard wrote|is a record|is an SQLite"):
            refuse_output(out, None, kind=PAGE)
    assert out.read_bytes() == data



def test_a_damaged_parquet_file_is_refused_as_not_an_export_not_as_unreadable(run, tmp_path):
    """pyarrow raises OSError for a footer it cannot decode: read as a read failure, "cannot be read"."""
    bad = tmp_path / "bad.parquet"
    bad.write_bytes(b"PAR1" + b"\x07" * 64 + (64).to_bytes(4, "little") + b"PAR1")
    before = digest(bad)
    line = one_error(runner.invoke(app, ["record", "export", str(run), "--format", "parquet", "-o", str(bad)]))
    assert "exists and is not a Parquet ticks export cellguard wrote" in line and "before November 2026" in line, line
    assert digest(bad) == before
