"""Release store leftovers: a plan's runs are keyed by what its units map holds; old logs stay readable."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from cellguard.release import Store, create_bundle, evaluate_stage, load_plan, log, promote, run_stage
from cellguard.release.errors import GateError
from cellguard.release.promotion import plan_hash, runs_key
from release_helpers import CELL, ONE, write_plan

GATES = [{"metric": "success_rate", "min": 0}]
UNITS_RUN = {"name": "one", "seed": 5, "acceptance_cycles": 1, "robot": "lerobot:so101_follower?units=u.yaml"}
# what 5ef966b's cellguard logged for the plan ``_units_plan`` writes (its text alone: the units map unread)
HEAD_PLAN_SHA256 = "bcbf22437a5151e486abb351532f317124bae45f219bb034c060dd6d3ba12cef"
HEAD_RUNS_SHA256 = "b7b4583c6978ed2caf28b322edcb4fb8595db1415a7138a4edb231d6fb27456d"


def _units_plan(folder: Path, units: str):
    """The sim stage of one plan text, written in ``folder`` beside a units map holding ``units``."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "u.yaml").write_text(units)
    return load_plan(write_plan(folder / "plan.yaml", {"sim": {"runs": [UNITS_RUN], "gates": GATES}}))["sim"]


def _site_with_a_record(tmp_path: Path) -> tuple[Store, str, Path]:
    """A site whose release ran one real sim run: (store, release id, that run's folder)."""
    store = Store(tmp_path / "site")
    bundle = create_bundle("scripted", None, CELL, None)
    store.add_bundle(bundle)
    promote(store, bundle.id, CELL, "sim")
    plain = load_plan(write_plan(tmp_path / "plain.yaml", {"sim": {"runs": [ONE], "gates": GATES}}))["sim"]
    result = run_stage(store, plain, CELL, "sim")
    return store, bundle.id, Path(result.folders[0])


def _count_as(store: Store, release: str, folder: Path, name: str, key: str) -> int:
    """A copy of the run in ``folder`` counted as made under runs key ``key``; its seq."""
    row = store.runs(CELL, "sim", release)[0]
    copy = store.site / "runs" / CELL / "sim" / f"09{len(store.run_rows()):02d}-{name}"
    shutil.copytree(folder, copy)
    store.add_run(row.record_id, CELL, "sim", release, name, copy, log.last_pointer_move(store, CELL, "sim").seq, key)
    return store.runs(CELL, "sim", release)[-1].seq


def _counted(store: Store, plan) -> set[int]:
    """The seqs of the runs an evaluation of ``plan`` at sim counts."""
    result = evaluate_stage(store, plan, CELL, "sim")
    return {seq for seq, _ in log.entries(store)[result.log_seq - 1].body["runs"]}


def test_one_plan_text_beside_two_units_maps_makes_two_plans_runs(tmp_path):
    """The same plan in two folders with other units maps: one's runs are not the other's evidence (keyed by the
    text alone, a run made in degrees counted for a plan in radians); the logged plan is the same."""
    a, b = _units_plan(tmp_path / "a", "unit: deg\n"), _units_plan(tmp_path / "b", "unit: rad\n")
    assert plan_hash(a) == plan_hash(b) == HEAD_PLAN_SHA256
    assert runs_key(a) != runs_key(b)
    store, release, folder = _site_with_a_record(tmp_path)
    made_under_a = _count_as(store, release, folder, "under-a", runs_key(a))
    assert made_under_a in _counted(store, a)
    assert made_under_a not in _counted(store, b)


def test_a_units_map_edited_in_place_starts_other_runs(tmp_path):
    before = runs_key(_units_plan(tmp_path / "a", "unit: deg\n"))
    assert runs_key(_units_plan(tmp_path / "a", "unit: rad\n")) != before


def test_runs_logged_by_the_older_cellguard_for_a_plan_with_a_units_map_count_no_more(tmp_path):
    """A row keyed as 5ef966b keyed it (the plan's text alone) was made under some units map, which one unknown: it
    counts no more under a plan naming one (counted, a map edited since let runs in other units pass its gates);
    its logged plan reads the same (its passes still stand)."""
    plan = _units_plan(tmp_path / "a", "unit: deg\n")
    store, release, folder = _site_with_a_record(tmp_path)
    older = _count_as(store, release, folder, "older", HEAD_RUNS_SHA256)
    assert older not in _counted(store, plan)
    assert plan_hash(plan) == HEAD_PLAN_SHA256


def test_a_plan_naming_no_file_keeps_the_key_the_older_cellguard_gave_it(tmp_path):
    plan = load_plan(write_plan(tmp_path / "plan.yaml", {"sim": {"runs": [ONE], "gates": GATES}}))["sim"]
    assert runs_key(plan) == "f80ffe8be61457178cc2a13dc062c2f12a981b3f3a08fd82f0705b4b946e7a70"  # 5ef966b's


def test_a_units_map_gone_is_one_error_naming_it(tmp_path):
    """No run is made without its units map (the bridge refuses it), so a plan whose map is gone keys no runs: it was
    keyed by its text alone, silently, its runs then mixing units."""
    plan = _units_plan(tmp_path / "a", "unit: deg\n")
    (tmp_path / "a" / "u.yaml").unlink()
    with pytest.raises(GateError, match=str(tmp_path / "a" / "u.yaml")):
        runs_key(plan)


def test_kept_evidence_no_live_release_can_read_is_dropped(tmp_path):
    """Three releases run in turn at sim: the first is neither current nor last_good there at the third's run, so
    the evidence kept for its run goes (it was kept for ever); the others' stays, signed."""
    from release_helpers import stored_release

    store = Store(tmp_path / "site")
    plan = load_plan(write_plan(tmp_path / "plan.yaml", {"sim": {"runs": [ONE], "gates": GATES}}))["sim"]
    records = []
    for note in ("a", "b", "c"):
        promote(store, stored_release(store, note), CELL, "sim")
        run_stage(store, plan, CELL, "sim")
        records.append(store.runs(CELL, "sim", store.pointers(CELL, "sim").current)[-1].record_id)
    kept = {digest[:16] for digest, _ in store.kept_bodies()}
    assert kept == set(records[1:]), (kept, records)
    assert log.verify_log(store) == []


def test_a_frozen_action_maps_path_reads_back_as_written_in_the_policy_spec():
    """The release's ?map= was joined unencoded: a path holding '&', '%', '#' or '+' named another file, or options."""
    from cellguard.options import split_options
    from cellguard.release.bundle import Bundle

    for path in ("/m/a&b=c.yaml", "/m/50%.yaml", "/m/a+b #1.yaml"):
        for spec in ("onnx:/p/model.onnx", "onnx:/p/model.onnx?dt=0.02"):
            bundle = Bundle("0" * 16, {"policy": {"spec": spec}, "action_map": {"path": path}})
            target, options = split_options(bundle.policy_spec.partition(":")[2], None, "policy", "")
            assert target == "/p/model.onnx" and options["map"] == path, bundle.policy_spec


def test_a_units_file_with_a_plus_in_its_name_is_part_of_the_plans_key(tmp_path):
    """Read form-decoded, ?units=a+b.yaml named 'a b.yaml', unreadable: the plan was keyed by its text alone."""
    from cellguard.release.plan import robot_files

    (tmp_path / "a+b.yaml").write_text("unit: deg\n")
    files = robot_files([{"robot": f"lerobot:so101_follower?port=/dev/null&units={tmp_path / 'a+b.yaml'}"}])
    assert [f[:2] for f in files] == [[0, "units"]]
