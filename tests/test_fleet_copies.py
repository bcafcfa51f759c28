"""A runs folder holding a run twice (a ``latest`` link, a backup copy) and one holding a record too short to
diagnose (``cellguard excite``'s), pushed to the real PostgreSQL server: each finding is counted and sent once, so
``min_group_size`` still keeps a lone finding at the site; the short record is left out in one warning line and
the others go."""

from __future__ import annotations

import datetime as dt
import json
import shutil

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.fleet.export import export_batch
from cellguard.fleet.from_record import site_signatures
from cellguard.fleet.policy import DataPolicy
from cellguard.fleet.signature import Signature
from cellguard.runtime import run_scenario
from cellguard.scenario import parse_scenario

psycopg = pytest.importorskip("psycopg", reason="the fleet store tests need psycopg: pip install 'cellguard[fleet]'")

from cellguard.fleet.store import FleetStore  # noqa: E402
from fleet_server import admin_dsn_or_skip, store_name  # noqa: E402

TODAY = dt.datetime.now(dt.timezone.utc).date()
KEY = b"site-secret-of-the-tests"


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    dsn = admin_dsn_or_skip()
    root = tmp_path_factory.mktemp("copies")
    run_scenario(parse_scenario({"cell": "arm-pick-place", "seed": 11, "acceptance_cycles": 5, "production_cycles": 4,
                                 "faults": [{"kind": "fixture_shift", "at_cycle": 6, "dx_mm": 5.0, "dy_mm": 1.0}]}),
                 root / "run")
    (root / "once").mkdir()
    (root / "once" / "run-1").symlink_to("../run")
    (root / "twice").mkdir()  # the probe's folder: a link to the run, a link to the link, and a backup copy
    (root / "twice" / "run-1").symlink_to("../run")
    (root / "twice" / "latest").symlink_to("run-1")
    shutil.copytree(root / "run", root / "twice" / "run.bak", symlinks=True)
    store = FleetStore(dsn, store_name("copies"))
    store.install(reset=True)
    return root, store.add_tenant("ta")


def push(root, folder, site: str, export: str, dsn: str):
    (root / f"{site}.yaml").write_text(f"tenant: ta\nsite: {site}\nexport: {export}\nmin_group_size: 2\n")
    return CliRunner().invoke(app, ["fleet", "push", str(root / folder), "--policy", str(root / f"{site}.yaml"),
                                    "--site-dir", str(root / f"site-{site}"), "--json"],
                              env={"CELLGUARD_FLEET_DSN": dsn})


def test_aggregates_count_a_run_held_twice_once(env):
    root, dsn = env
    once = push(root, "once", "s-once", "aggregates_only", dsn)
    twice = push(root, "twice", "s-twice", "aggregates_only", dsn)
    assert once.exit_code == 0 and twice.exit_code == 0, twice.output
    one, two = json.loads(once.stdout), json.loads(twice.stdout)
    assert (two["rows"], two["withheld_rows"]) == (one["rows"], one["withheld_rows"])  # as if held once
    assert two["withheld_rows"] >= 1  # a lone finding stays at the site under min_group_size 2
    assert two["copies_skipped"] == 2 and one["copies_skipped"] == 0
    said = CliRunner().invoke(app, ["fleet", "push", str(root / "twice"), "--policy", str(root / "s-twice.yaml"),
                                    "--site-dir", str(root / "site-s-twice")], env={"CELLGUARD_FLEET_DSN": dsn})
    assert said.exit_code == 0 and "; 2 copies of records already read skipped;" in said.stdout


def test_signatures_of_a_run_held_twice_are_sent_once_and_none_called_already_stored(env):
    root, dsn = env
    first = json.loads(push(root, "twice", "s-sig", "signatures", dsn).stdout)
    single = json.loads(push(root, "once", "s-sig1", "signatures", dsn).stdout)
    assert first["rows"] == single["rows"] >= 1
    assert (first["new_rows"], first["duplicate_rows"], first["copies_skipped"]) == (first["rows"], 0, 2)


def test_a_record_met_twice_is_diagnosed_once_and_named(env):
    root, _ = env
    copies: list[str] = []
    sigs = site_signatures(root / "twice", DataPolicy("ta", "s-x"), copies=copies)
    once = site_signatures(root / "once", DataPolicy("ta", "s-x"))
    assert sorted(map(repr, sigs)) == sorted(map(repr, once)) and len(copies) == 2
    assert {c.rsplit("/", 1)[1] for c in copies} == {"run-1", "run.bak"}  # "latest" came first in name order


def test_a_record_too_short_to_diagnose_is_left_out_and_the_others_go(env):
    root, dsn = env
    runs = root / "mixed"
    runs.mkdir()
    (runs / "a").symlink_to("../run")
    made = CliRunner().invoke(app, ["excite", "arm-pick-place", "--seconds", "7", "--out", str(runs / "ex")])
    assert made.exit_code == 0, made.output
    result = push(root, "mixed", "s-mixed", "signatures", dsn)
    assert result.exit_code == 1, result.output
    out = json.loads(result.stdout)
    assert out["rows"] >= 1 and out["new_rows"] == out["rows"]  # the ordinary run went
    warnings = [line for line in result.stderr.splitlines() if line.startswith("warning:")]
    assert len(warnings) == 1 and str(runs / "ex") in warnings[0] and "acceptance cycles" in warnings[0]
    assert "Traceback" not in result.output


def _sig(cause: str, n: int) -> Signature:
    return Signature("t-a", "s-1", TODAY.isoformat(), cause, 0.8, "arm5", "arm-pick-place",
                     {"current_rms.elbow": 6.0 + n}, 7, 1)


POOL = [_sig(c, n) for c in ("friction", "servo") for n in range(3)]


@settings(max_examples=40, deadline=None)
@given(st.integers(0, len(POOL) - 1), st.integers(2, 4))
def test_the_same_finding_of_separate_runs_counts_once_per_run(picked, runs):
    """Copies of one record are read once (above); separate runs whose findings come out alike (a scenario run again
    with its seed) are separate findings: counted once each, a real group of two was withheld."""
    policy = DataPolicy("t-a", "s-1", "aggregates_only", min_group_size=runs)
    batch = export_batch([POOL[picked]] * runs, policy, TODAY, key=KEY)
    assert [a["signatures"] for a in batch.aggregates] == [runs] and batch.withheld_rows == 0, batch
