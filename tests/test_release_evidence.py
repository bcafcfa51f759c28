"""A stage's evidence is read from its own site, from any working directory, and only as the records counted:
a record put in a run's place, or a run folder gone, never counts towards a pass; the verdict is still decided
and a failing production release still rolls back. Two runs started at once never share a folder."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from release_helpers import CELL, KNOCKED, sim_and_production_plan, stored_release, to_production

from cellguard.release import Store, evaluate_stage, log, promote, run_stage
from cellguard.release.errors import StageError
from cellguard.release.evidence import record_id
from cellguard.release.promotion import runs_key


def _lost_run(store, release: str, stage: str, made_under: str) -> None:
    """A counted run whose folder is not there (as a run counted from another working directory was), made under
    ``made_under`` (``runs_key``)."""
    moved = log.last_pointer_move(store, CELL, stage)
    store.add_run("0" * 16, CELL, stage, release, "lost", store.site / "runs" / CELL / stage / "0099-lost", moved.seq,
                  made_under)


def test_a_site_reads_its_own_runs_from_any_working_directory_and_when_copied(tmp_path, monkeypatch):
    plan = sim_and_production_plan(tmp_path)
    monkeypatch.chdir(tmp_path)
    store = Store("site")  # relative, as `--site site`
    release = stored_release(store, "v1")
    promote(store, release, CELL, "sim")
    assert run_stage(store, plan["sim"], CELL, "sim").verdict == "pass"
    store.close()
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    result = evaluate_stage(Store("../site"), plan["sim"], CELL, "sim")
    assert result.verdict == "pass" and result.refused == ()
    shutil.copytree(tmp_path / "site", tmp_path / "copy")
    shutil.rmtree(tmp_path / "site" / "runs")  # the copy reads its own records, not the original's
    copied = evaluate_stage(Store(tmp_path / "copy"), plan["sim"], CELL, "sim")
    assert copied.verdict == "pass" and copied.evidence == result.evidence


def test_a_run_that_cannot_be_read_is_never_a_pass_and_a_failing_production_release_still_rolls_back(tmp_path):
    plan, store = sim_and_production_plan(tmp_path), Store(tmp_path / "site")
    first, second = stored_release(store, "v1"), stored_release(store, "v2")
    to_production(store, first)
    assert run_stage(store, plan["production"], CELL, "production").verdict == "pass"
    _lost_run(store, first, "production", runs_key(plan["production"]))
    again = evaluate_stage(store, plan["production"], CELL, "production")
    assert again.verdict == "inconclusive" and "0099-lost" in again.refused[0]  # its real run passed: not enough
    to_production(store, second)
    (tmp_path / "knocked").mkdir()
    knocked = sim_and_production_plan(tmp_path / "knocked", KNOCKED)["production"]  # the plan in force, failing
    _lost_run(store, second, "production", runs_key(knocked))  # among its runs
    result = run_stage(store, knocked, CELL, "production")
    assert result.verdict == "fail" and result.rolled_back_to == first
    assert any("0099-lost" in why for why in result.refused)
    assert store.pointers(CELL, "production").current == first
    assert log.entries(store)[-2].body["refused"] == list(result.refused)  # the gates entry names it
    assert log.verify_log(store) == []


def test_a_record_put_in_a_failed_runs_place_is_refused_naming_the_folder(tmp_path):
    """The passing record of release A copied over release B's failed run made B's gates pass, with the failed
    record's id logged as the evidence."""
    plan, store = sim_and_production_plan(tmp_path), Store(tmp_path / "site")
    (tmp_path / "knocked").mkdir()
    knocked = sim_and_production_plan(tmp_path / "knocked", KNOCKED)["sim"]  # a plan whose run fails
    first, second = stored_release(store, "v1"), stored_release(store, "v2")
    promote(store, first, CELL, "sim")
    passed = run_stage(store, plan["sim"], CELL, "sim")
    promote(store, second, CELL, "sim")
    failed = run_stage(store, knocked, CELL, "sim")
    assert passed.verdict == "pass" and failed.verdict == "fail"
    good, bad = Path(passed.folders[0]), Path(failed.folders[0])
    shutil.copyfile(good / "record.mcap", bad / "record.mcap")
    swapped = evaluate_stage(store, knocked, CELL, "sim")
    assert swapped.verdict == "inconclusive" and swapped.evidence == ()
    assert str(bad) in swapped.refused[0] and f"not {failed.evidence[0]} that was counted" in swapped.refused[0]
    store.db.execute("UPDATE runs SET record_id=? WHERE release=?", (record_id(bad), second))  # the row too
    forged = evaluate_stage(store, knocked, CELL, "sim")
    assert forged.verdict == "inconclusive" and f"a run of release {first} at sim" in forged.refused[0]
    with pytest.raises(StageError, match=r"ended inconclusive .*, runs not read as evidence; log entry"):
        promote(store, second, CELL, "bench")


def test_a_run_folder_another_run_took_first_is_left_alone(tmp_path, monkeypatch):
    """Two runs started at once picked the same number; the later one takes the next folder."""
    import cellguard.release.promotion as promotion

    plan, store = sim_and_production_plan(tmp_path), Store(tmp_path / "site")
    promote(store, stored_release(store, "v1"), CELL, "sim")
    taken = store.site / "runs" / CELL / "sim" / "0001-one"
    taken.mkdir(parents=True)
    (taken / "theirs.txt").write_text("the other run's")
    monkeypatch.setattr(promotion, "_next_number", lambda store: 1)  # as it was when the other run picked it
    result = run_stage(store, plan["sim"], CELL, "sim")
    assert result.verdict == "pass" and result.folders[0].endswith("0002-one")
    assert [p.name for p in taken.iterdir()] == ["theirs.txt"]
