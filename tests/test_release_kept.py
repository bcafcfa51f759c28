"""A counted run is read from its record, and diagnosed, once: its evidence is kept in the store, signed by the gates
entry that kept it, and read in place of the record while the record still hashes to it, with the verdicts the
records give. A kept body edited in the store is never read (verify names it); a body of another cellguard version
is not read either."""

from __future__ import annotations

import numpy as np
import pytest
from release_helpers import CELL, KNOCKED, ONE, cli, edit_store, stored_release, write_plan

import cellguard.release.evidence as evidence
import cellguard.release.kept as kept
import cellguard.release.metrics.drift as drift
from cellguard.release import Store, evaluate_stage, load_plan, log, promote, run_stage
from cellguard.release.store import KEPT_TABLE

SAFETY = [{"metric": "success_rate", "min": 1.0}, {"metric": "protective_stops", "max": 0},
          {"metric": "limit_violations", "max": 0}, {"metric": "chunk_seam_jump_max_mrad", "max": 60},
          {"metric": "cycle_time_p95_s", "max": 6.0}, {"metric": "interventions_per_hour", "max": 10}]


def _site(tmp_path, run: dict, gates: list):
    """A plan of ``run`` at sim with ``gates``, and a store where a scripted release is current there."""
    plan = load_plan(write_plan(tmp_path / "plan.yaml", {"sim": {"runs": [run], "gates": gates}}))["sim"]
    store = Store(tmp_path / "site")
    promote(store, stored_release(store, "v1"), CELL, "sim")
    return plan, store


def _calls(monkeypatch, module, name: str) -> list:
    """Each call of ``module.name`` from now on (the function itself runs)."""
    calls, real = [], getattr(module, name)

    def counted(*args, **kwargs):
        calls.append(args)
        return real(*args, **kwargs)

    monkeypatch.setattr(module, name, counted)
    return calls


def _gates(result) -> list[dict]:
    return [g.to_dict() for g in result.gates]


def _signed(store, result) -> list[str]:
    return log.entries(store)[result.log_seq - 1].body[log.KEPT]


def test_each_counted_run_is_read_from_its_record_once_and_judged_as_its_record(tmp_path, monkeypatch):
    """Every evaluation read and reduced every run the release had made there (200 one-cycle runs: 12 s each
    `release run`)."""
    plan, store = _site(tmp_path, ONE, SAFETY)
    reads = _calls(monkeypatch, evidence, "open_record")
    results = [run_stage(store, plan, CELL, "sim") for _ in range(3)]
    assert len(reads) == 3 and [len(r.evidence) for r in results] == [1, 2, 3]  # the new run's record alone
    assert [r.verdict for r in results] == ["pass"] * 3
    assert [len(_signed(store, r)) for r in results] == [1, 1, 1]  # each entry signs the body it kept
    monkeypatch.setattr(kept, "_code", lambda: "another")  # bodies another cellguard kept: its records are read
    upgraded = evaluate_stage(store, plan, CELL, "sim")
    assert len(reads) == 6 and len(_signed(store, upgraded)) == 3 and _gates(upgraded) == _gates(results[-1])
    edit_store(store.site, f"DROP TABLE {KEPT_TABLE}")  # nothing kept: every record read, the same verdict
    fresh = evaluate_stage(store, plan, CELL, "sim")
    assert len(reads) == 9 and _gates(fresh) == _gates(results[-1]) and fresh.evidence == results[-1].evidence


@pytest.fixture(scope="module")
def drifting(tmp_path_factory):
    """Five acceptance cycles and two with the fixture moved 5 mm (drift alarms), evaluated once."""
    run = {"name": "moved", "seed": 10, "acceptance_cycles": 5, "production_cycles": 2,
           "faults": [{"kind": "fixture_shift", "at_cycle": 5, "dx_mm": 5.0}]}
    plan, store = _site(tmp_path_factory.mktemp("kept"), run, [{"metric": "drift_alarms", "max": 0}, *SAFETY])
    return plan, store, run_stage(store, plan, CELL, "sim")


def test_a_run_is_diagnosed_once_and_its_kept_evidence_reads_as_its_record(drifting, monkeypatch):
    """The diagnosis of every counted run ran again at every evaluation (0.1 s a production run)."""
    plan, store, first = drifting
    alarms = next(g for g in first.gates if g.metric == "drift_alarms")
    assert first.verdict == "fail" and alarms.value > 0 and "statistic" in alarms.evidence[0]
    diagnosed, reads = _calls(monkeypatch, drift, "diagnose"), _calls(monkeypatch, evidence, "open_record")
    again = evaluate_stage(store, plan, CELL, "sim")
    assert diagnosed == [] and reads == [] and _gates(again) == _gates(first) and _signed(store, again) == []
    (row,) = store.runs(CELL, "sim", first.release)
    folder = store.run_folder(row)
    as_kept = kept.Kept(store, log.entries(store)).read(folder, row.name)
    as_read = evidence.load_run(folder, row.name)
    assert as_kept.derived["drift"]["alarms"] and as_read.derived == {}  # the one from the store, the other read
    for name in ("record_id", "record_sha256", "name", "folder", "context", "cycles", "events", "limits", "shadow"):
        assert repr(getattr(as_kept, name)) == repr(getattr(as_read, name)), name  # repr: NaN features compare
    got, want = as_kept.chunks, as_read.chunks
    assert np.array_equal(got.latency_ms, want.latency_ms) and len(got.latency_ms) > 10
    assert (got.seams, got.worst_seam_mrad, got.worst_seam_t_ns) == (want.seams, want.worst_seam_mrad,
                                                                      want.worst_seam_t_ns)


def test_a_kept_body_edited_in_the_store_is_never_read_and_verify_names_it(tmp_path, monkeypatch):
    """A failed cycle turned success in the kept evidence must not turn the verdict."""
    plan, store = _site(tmp_path, KNOCKED, [{"metric": "success_rate", "min": 1.0}])
    failed = run_stage(store, plan, CELL, "sim")
    assert failed.verdict == "fail"
    edit_store(store.site, f"UPDATE {KEPT_TABLE} SET body = replace(body, '\"success\":false', '\"success\":true')")
    assert '"success":true' in store.kept_bodies()[0][1]
    verify = cli("verify", "--site", str(store.site))
    said = " ".join(verify.stdout.split())
    assert verify.exit_code == 1 and f"the evidence kept for record {failed.evidence[0]}" in said
    assert "edited outside cellguard" in said
    reads = _calls(monkeypatch, evidence, "open_record")
    again = evaluate_stage(store, plan, CELL, "sim")
    assert len(reads) == 1 and again.verdict == "fail" and _gates(again) == _gates(failed)
    assert cli("verify", "--site", str(store.site)).exit_code == 0  # kept again as read from its record


def test_a_kept_table_of_another_shape_keeps_nothing_and_verify_names_it(tmp_path, monkeypatch):
    """Every `release run` failed on it (nothing logged: a failing production release would not roll back), and
    verify said the store was clean."""
    plan, store = _site(tmp_path, ONE, SAFETY)
    run_stage(store, plan, CELL, "sim")
    edit_store(store.site, f"DROP TABLE {KEPT_TABLE}")
    edit_store(store.site, f"CREATE TABLE {KEPT_TABLE} (x TEXT)")
    reads = _calls(monkeypatch, evidence, "open_record")
    again = run_stage(store, plan, CELL, "sim")
    assert again.verdict == "pass" and len(reads) == 2 and _signed(store, again) == []  # read from the records
    verify = cli("verify", "--site", str(store.site))
    said = " ".join(verify.stdout.split())
    assert verify.exit_code == 1 and "the kept evidence table is not one cellguard made (columns x;" in said


def test_a_signed_body_put_under_another_records_key_is_named(tmp_path):
    plan, store = _site(tmp_path, ONE, SAFETY)
    for _ in range(2):
        run_stage(store, plan, CELL, "sim")
    (a, _), (b, _) = store.kept_bodies()
    edit_store(store.site, f"UPDATE {KEPT_TABLE} SET record_sha256 = 'x' || record_sha256 WHERE record_sha256 = '{a}'")
    edit_store(store.site, f"UPDATE {KEPT_TABLE} SET record_sha256 = '{a}' WHERE record_sha256 = '{b}'")
    edit_store(store.site, f"UPDATE {KEPT_TABLE} SET record_sha256 = '{b}' WHERE record_sha256 = 'x{a}'")
    verify = cli("verify", "--site", str(store.site))
    said = " ".join(verify.stdout.split())
    assert verify.exit_code == 1 and f"the evidence kept for record {a[:16]}" in said and f"record {b[:16]}" in said


def test_a_record_swapped_while_it_is_read_is_never_kept_as_the_record_counted(tmp_path, monkeypatch):
    """Read while another run's record stood in its place (put back before the file was hashed by its path), the
    other record's evidence was kept under the counted record's hash, and every later evaluation read it."""
    plan, store = _site(tmp_path, KNOCKED, [{"metric": "success_rate", "min": 1.0}])
    first = run_stage(store, plan, CELL, "sim")
    clean = load_plan(write_plan(tmp_path / "clean.yaml", {"sim": {"runs": [ONE], "gates": SAFETY}}))["sim"]
    run_stage(store, clean, CELL, "sim")
    knocked, other = (store.run_folder(r) for r in store.runs(CELL, "sim", first.release))
    edit_store(store.site, f"DROP TABLE {KEPT_TABLE}")  # nothing kept: the records are read
    real = evidence.open_record
    monkeypatch.setattr(evidence, "open_record", lambda folder: real(other if folder == knocked else folder))
    swapped = evaluate_stage(store, plan, CELL, "sim")
    assert len(swapped.refused) == 1 and str(knocked) in swapped.refused[0]
    monkeypatch.setattr(evidence, "open_record", real)
    again = evaluate_stage(store, plan, CELL, "sim")
    assert again.refused == () and _gates(again) == _gates(first) and again.verdict == "fail"  # its own, as read
