"""A `release run` refused because another command changed its stage while its runs went names what changed: which
pointer, from what to what, and the log entry that set it. It named the stage's last promotion, made before either
run started, and said "moved" when another run's gates had only made their release last_good."""

from __future__ import annotations

import re
import sqlite3

import pytest
from release_helpers import CELL, ONE, cli, log_pass, stored_release, write_plan

import cellguard.runtime
from cellguard.release import Store, load_plan, log, promote, rollback, run_stage, verify_log
from cellguard.release.errors import StageError
from cellguard.release.store import STORE_FILE


def _while_runs_go(monkeypatch, act) -> list[int]:
    """Run ``act`` (another command, on its own connection) once, after the next stage run is recorded and before
    its gates are evaluated; the log entry ``act`` returns lands in the list returned."""
    real, landed = cellguard.runtime.run_scenario, []

    def run_then_act(*args, **kwargs):
        result = real(*args, **kwargs)
        if not landed:
            landed.append(0)  # before ``act``: a run it makes comes through here too
            landed[0] = act()
        return result

    monkeypatch.setattr(cellguard.runtime, "run_scenario", run_then_act)
    return landed


@pytest.fixture
def site(tmp_path):
    """A site whose plan in force runs one cycle at sim, two releases (v1, v2) in its store."""
    store = Store(tmp_path / "site")
    write_plan(store.site / "release-plan.yaml", {"sim": {"runs": [ONE], "gates": [{"metric": "success_rate",
                                                                                      "min": 1.0}]}})
    return store, stored_release(store, "v1"), stored_release(store, "v2")


def test_another_runs_pass_that_made_its_release_last_good_is_named_and_not_called_a_move(site, monkeypatch):
    """The hostile probe's race: two `release run` of the same stage at once, the first pass there. The second named
    the promotion made before both (log entry 1) and said current was moved; the first run's gates had set last_good."""
    store, v1, _ = site
    promote(store, v1, CELL, "sim")
    plan = load_plan(store.site / "release-plan.yaml")["sim"]
    landed = _while_runs_go(monkeypatch, lambda: run_stage(Store(store.site), plan, CELL, "sim").log_seq)
    result = cli("run", "--cell", CELL, "--stage", "sim", "--site", str(store.site))
    error = result.stderr.splitlines()[-1]  # after the run's progress lines
    assert result.exit_code == 2 and error.startswith(f"error: sim on {CELL}: "), result.output
    assert landed == [2] and [e.body["kind"] for e in log.entries(store)] == ["promote", "gates"]
    assert (f"sim on {CELL}: current {v1}, last_good {v1} (last_good was none; log entry 2, a pass of {v1}'s gates), "
            f"changed by another command while the runs of {v1} were going or evaluated: their gates were not logged "
            f"and nothing moved; the records stay in ") in error
    assert "moved by" not in error and "log entry 1" not in error
    assert (store.pointers(CELL, "sim").current, store.pointers(CELL, "sim").last_good) == (v1, v1)
    assert verify_log(store) == []


def _promote_v2(store, v1, v2):
    return promote(store, v2, CELL, "sim").seq


def _roll_back(store, v1, v2):
    return rollback(store, CELL, "sim").seq


def _pass_then_promote_v2(store, v1, v2):
    log_pass(store, "sim", v1)
    return promote(store, v2, CELL, "sim").seq


def _promote_v2_and_roll_back(store, v1, v2):
    promote(store, v2, CELL, "sim")
    return rollback(store, CELL, "sim").seq


def _promote_v2_then_pass_it(store, v1, v2):
    promote(store, v2, CELL, "sim")
    log_pass(store, "sim", v2)
    return log.entries(store)[-1].seq


def _wipe_the_log_and_pointers(store, v1, v2):
    """A hand edit that leaves a whole, empty log: every entry, the head and the pointers deleted together."""
    with sqlite3.connect(store.site / STORE_FILE) as db:
        db.executescript("DELETE FROM log; DELETE FROM pointers; DELETE FROM meta WHERE key LIKE 'log_%';")
    return 0


@pytest.mark.parametrize("before, act, said", [
    ([], _promote_v2, "current {v2}, last_good none (current was {v1}; log entry {seq}, a promotion of {v2}), moved"),
    (["pass v1", "v2"], _roll_back,
     "current {v1}, last_good {v1} (current was {v2}; log entry {seq}, a rollback to {v1}), moved"),
    ([], _pass_then_promote_v2,
     "current {v2}, last_good {v1} (current was {v1}, last_good was none; log entry {seq}, a promotion of {v2}), "
     "moved"),
    (["pass v1"], _promote_v2_and_roll_back,
     "current {v1}, last_good {v1} (current left {v1} and came back; log entry {seq}, a rollback to {v1}), moved"),
    ([], _promote_v2_then_pass_it,  # the promotion moved current, the pass set last_good: both named (only the pass was)
     "current {v2}, last_good {v2} (current was {v1}, last_good was none; log entry {prev}, a promotion of {v2}; "
     "log entry {seq}, a pass of {v2}'s gates), moved"),
    ([], _wipe_the_log_and_pointers, "current none, last_good none (current was {v1}; no log entry sets them), moved"),
], ids=["current-by-promotion", "current-by-rollback", "both", "current-away-and-back", "moved-then-passed",
        "log-wiped"])
def test_a_stage_moved_while_its_runs_went_names_the_pointers_changed_and_the_entry(site, monkeypatch, before, act,
                                                                                      said):
    store, v1, v2 = site
    promote(store, v1, CELL, "sim")
    for step in before:
        if step == "pass v1":
            log_pass(store, "sim", v1)
        else:
            promote(store, v2, CELL, "sim")
    runs_of = store.pointers(CELL, "sim").current
    landed = _while_runs_go(monkeypatch, lambda: act(Store(store.site), v1, v2))
    plan = load_plan(store.site / "release-plan.yaml")["sim"]
    with pytest.raises(StageError) as refused:
        run_stage(store, plan, CELL, "sim")
    seq = landed[0]
    assert seq == (log.entries(store)[-1].seq if seq else log.size(store))  # no gates logged after the other's entry
    want = said.format(v1=v1, v2=v2, seq=seq, prev=seq - 1)
    assert re.search(rf"^sim on {CELL}: {re.escape(want)} by another command while the runs of {runs_of} were going "
                     rf"or evaluated: their gates were not logged and nothing moved; ", str(refused.value)), \
        str(refused.value)
    assert verify_log(store) == []
