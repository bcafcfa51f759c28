"""Commands racing `release run`, and a store another process holds locked: a stage's gates act only on the
release its runs started on (a promotion that lands meanwhile is neither rolled back nor undone), and a lock
is one line, exit 2, with nothing moved and a written record kept."""

from __future__ import annotations

import sqlite3

import pytest
from release_helpers import CELL, KNOCKED, ONE, cli, log_pass, sim_and_production_plan, stored_release

import cellguard.release.store as store_module
from cellguard.release import Store, log, promote, run_stage, verify_log
from cellguard.release.errors import ReleaseError, StageError
from cellguard.release.store import STORE_FILE


def _through(store, release: str, last: str) -> None:
    """``release`` promoted stage by stage up to ``last``, each earlier stage's gates logged as passed."""
    for stage, before in (("sim", None), ("bench", "sim"), ("pilot", "bench"), ("production", "pilot")):
        if before:
            log_pass(store, before, release)
        promote(store, release, CELL, stage)
        if stage == last:
            return


def _when_gates_are_logged(store, act) -> None:
    """Run ``act`` (another command, on its own connection) once, just before ``store`` takes the write lock to
    log its gates: after the stage's runs were counted and evaluated."""
    def trace(sql):
        if sql == "BEGIN IMMEDIATE":
            store.db.set_trace_callback(None)
            act()
    store.db.set_trace_callback(trace)


def test_a_promotion_landing_during_production_gates_is_not_rolled_back(tmp_path):
    """Production's failing gates rolled back the release promoted meanwhile and printed a stale last_good."""
    plan, store = sim_and_production_plan(tmp_path, KNOCKED), Store(tmp_path / "site")
    good, failing, newcomer = (stored_release(store, n) for n in ("v1", "v2", "v3"))
    _through(store, good, "production")
    log_pass(store, "production", good)
    _through(store, failing, "production")
    _through(store, newcomer, "pilot")
    log_pass(store, "pilot", newcomer)
    _when_gates_are_logged(store, lambda: promote(Store(store.site), newcomer, CELL, "production"))
    with pytest.raises(StageError, match=rf"current {newcomer}, last_good {good} .*moved by another command while "
                                         rf"the runs of {failing} were going.*nothing moved"):
        run_stage(store, plan["production"], CELL, "production")
    assert store.pointers(CELL, "production").current == newcomer
    assert [e.body["kind"] for e in log.entries(store)][-1] == "promote"  # no gates, no rollback after it
    assert verify_log(store) == []


def test_a_promotion_landing_during_sim_gates_is_not_undone(tmp_path):
    """A passing first evaluation set the pointers from what it read before: the racing promotion was undone and
    `verify` then called the store edited by hand."""
    plan, store = sim_and_production_plan(tmp_path, ONE), Store(tmp_path / "site")
    first, second = stored_release(store, "v1"), stored_release(store, "v2")
    promote(store, first, CELL, "sim")
    _when_gates_are_logged(store, lambda: promote(Store(store.site), second, CELL, "sim"))
    with pytest.raises(StageError, match="moved by another command"):
        run_stage(store, plan["sim"], CELL, "sim")
    assert store.pointers(CELL, "sim").current == second
    assert verify_log(store) == []


def _lock(site):
    """Another process's write lock on the store (a sqlite3 shell in BEGIN IMMEDIATE, a backup)."""
    holder = sqlite3.connect(site / STORE_FILE, isolation_level=None)
    holder.execute("BEGIN IMMEDIATE")
    return holder


@pytest.fixture
def short_wait(monkeypatch):
    monkeypatch.setattr(store_module, "LOCK_WAIT_S", 0.1, raising=False)


def test_a_locked_store_is_one_line_exit_2_and_nothing_moves(tmp_path, short_wait):
    site = tmp_path / "site"
    store = Store(site)
    first, second = stored_release(store, "v1"), stored_release(store, "v2")
    _through(store, first, "production")
    log_pass(store, "production", first)
    _through(store, second, "production")
    before = len(log.entries(store))
    holder = _lock(site)
    try:
        for args in (("rollback", "--cell", CELL), ("promote", first, "--cell", CELL, "--to", "sim"),
                     ("create", "--policy", "scripted", "--profile", CELL, "--note", "v3")):
            result = cli(*args, "--site", str(site))
            assert result.exit_code == 2 and result.stderr.count("\n") == 1, (args, result.output)
            assert f"{STORE_FILE} is locked by another process" in result.stderr
    finally:
        holder.close()
    assert len(log.entries(store)) == before and store.pointers(CELL, "production").current == second


def test_a_run_whose_record_could_not_be_counted_says_so_and_keeps_it(tmp_path, short_wait):
    plan, store = sim_and_production_plan(tmp_path, ONE), Store(tmp_path / "site")
    promote(store, stored_release(store, "v1"), CELL, "sim")
    holders = []
    with pytest.raises(ReleaseError, match=r"its record in .*0001-one is kept but could not be counted \(.*locked"):
        run_stage(store, plan["sim"], CELL, "sim", on_run=lambda _: holders.append(_lock(store.site)))
    holders[0].close()
    assert (store.site / "runs" / CELL / "sim" / "0001-one" / "record.mcap").is_file()
    assert store.run_rows() == {} and [e.body["kind"] for e in log.entries(store)] == ["promote"]
