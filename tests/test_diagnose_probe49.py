"""Probe 49's diagnosis answers: a record's copy is no earlier incident of itself, a format-1 record's baseline.json
is bound to its run's epoch, and `diagnose --json` is strict JSON (the report's table a dash)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from test_record_recover_format1 import _as_format_1
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.diagnose.cause import Finding
from cellguard.diagnose.recovery import advice
from cellguard.diagnose.site_history import save_fixes, site_history

runner = CliRunner()
ARM = "cell: arm-pick-place\nseed: {seed}\nacceptance_cycles: {acc}\nproduction_cycles: {prod}\n"
ELBOW = "faults:\n  - {kind: servo_gain, joint: elbow, factor: 0.7, at_cycle: 0}\n"


def _run(tmp: Path, name: str, seed: int, acc: int, prod: int, faults: str = "") -> Path:
    (tmp / f"{name}.yaml").write_text(ARM.format(seed=seed, acc=acc, prod=prod) + faults)
    done = runner.invoke(app, ["run", str(tmp / f"{name}.yaml"), "--out", str(tmp / name)])
    assert done.exit_code == 0, done.output
    return tmp / name


# -- 1. a sibling with the same record_id is the same incident --------------------------------------------------
def test_a_copy_of_the_record_is_no_earlier_incident_and_no_record_counts_twice(tmp_path):
    """A `record recover` copy beside its original read as an earlier incident of itself ("fixed it in 3 of 3"),
    and two copies of another record doubled its counts under "1 record(s)"."""
    row = {"cause": "intermittent_slip", "cycle": 10, "recovery": "retry_grasp", "tried": 3, "fixed": 3}
    for name, record_id in (("run-7", "r7"), ("run-7-recovered", "r7"), ("run-8", "r8"), ("run-8-backup", "r8"),
                            ("run-8-copy2", "r8")):
        (tmp_path / name).mkdir()
        save_fixes(tmp_path / name, {"record_id": record_id, "site": "s"}, [row])
    (tmp_path / "run-9").mkdir()  # a record of its own, never diagnosed: r7 and r8 once each (3 copies of r8 read 9)
    advised = advice([Finding("intermittent_slip", 10, 0.9, ())], site_history(tmp_path / "run-9", "s"))
    assert [(r["tried"], r["fixed"], r["records"]) for r in advised[0]["recoveries"]] == [(6, 6, 2)]
    seen = {k: row[k] for k in ("cause", "recovery", "tried", "fixed")}
    assert site_history(tmp_path / "run-7", "s", "r7") == [{**seen, "record": "r8"}]
    advised = advice([Finding("intermittent_slip", 10, 0.9, ())], site_history(tmp_path / "run-7", "s", "r7"))
    assert [(r["tried"], r["fixed"], r["records"]) for r in advised[0]["recoveries"]] == [(3, 3, 1)]
    assert site_history(tmp_path / "run-8-backup", "s", "r8") == [{**seen, "record": "r7"}]


# -- 2. a format-1 record's baseline.json is bound to its run's epoch --------------------------------------------
@pytest.fixture(scope="module")
def format_1(tmp_path_factory) -> dict[str, Path]:
    """Two format-1 records of the same robot and profile (no record id): a healthy one and one whose elbow is
    weak from its first cycle."""
    tmp = tmp_path_factory.mktemp("f1")
    out = {}
    for name, seed, faults in (("healthy", 3, ""), ("weak", 5, ELBOW)):
        _as_format_1(_run(tmp, f"{name}-2", seed, 5, 2, faults), tmp / name)
        out[name] = tmp / name
    return out


def _swap(tmp: Path, baseline_of: Path, record_of: Path) -> Path:
    (tmp / "swap").mkdir()
    shutil.copy(baseline_of / "baseline.json", tmp / "swap")
    shutil.copy(record_of / "record.mcap", tmp / "swap")
    return tmp / "swap"


def test_another_format_1_records_baseline_is_refused(format_1, tmp_path):
    """Bound to record_id null, the weak record's baseline was taken for the healthy one's own: "unknown (elbow)",
    exit 0. It is bound to its run's epoch now: one line, exit 2, the file left as it is."""
    assert runner.invoke(app, ["diagnose", str(format_1["weak"])]).exit_code == 0
    stored = json.loads((format_1["weak"] / "baseline.json").read_text())
    assert stored["bound_to"]["record_id"] is None and stored["bound_to"]["epoch_wall_ns"]
    swap = _swap(tmp_path, format_1["weak"], format_1["healthy"])
    said = runner.invoke(app, ["diagnose", str(swap)])
    assert said.exit_code == 2, said.output
    assert "baseline is bound to epoch_wall_ns" in said.output and len(said.output.strip().splitlines()) == 1
    assert json.loads((swap / "baseline.json").read_text()) == stored


def test_an_older_unbound_baseline_is_kept_where_it_is_the_records_own_and_refused_where_not(format_1, tmp_path):
    """A baseline.json written before the epoch was bound: the record's own is read (and bound); another run's is
    refused, not diagnosed against."""
    for name in format_1:
        assert runner.invoke(app, ["diagnose", str(format_1[name])]).exit_code == 0
        path = format_1[name] / "baseline.json"
        raw = json.loads(path.read_text())
        raw["bound_to"].pop("epoch_wall_ns")
        path.write_text(json.dumps(raw))
    swap = _swap(tmp_path, format_1["weak"], format_1["healthy"])
    said = runner.invoke(app, ["diagnose", str(swap)])
    assert said.exit_code == 2, said.output
    assert "baseline is not this record's" in said.output
    own = runner.invoke(app, ["diagnose", str(format_1["healthy"])])
    assert own.exit_code == 0, own.output
    assert json.loads((format_1["healthy"] / "baseline.json").read_text())["bound_to"]["epoch_wall_ns"]


# -- 3. strict JSON, a dash in the report -------------------------------------------------------------------------
def test_no_good_cycle_before_the_fault_is_null_in_json_and_a_dash_in_the_report(tmp_path):
    """With no good cycle before the fault, changes[].last_good was NaN: `diagnose --json` printed invalid JSON and
    the report's "What changed" table "nan"."""
    acc = _run(tmp_path, "acc", 8, 5, 0)
    prod = _run(tmp_path, "prod", 9, 0, 3, ELBOW)
    said = runner.invoke(app, ["diagnose", str(prod), "--acceptance", str(acc), "--json"])
    assert said.exit_code in (0, 1), said.output

    def refuse(constant: str):
        raise AssertionError(f"not strict JSON: {constant}")

    doc = json.loads(said.stdout, parse_constant=refuse)
    assert doc["changes"] and all(c["last_good"] is None for c in doc["changes"])
    page = tmp_path / "r.html"
    assert runner.invoke(app, ["report", str(prod), "--acceptance", str(acc), "-o", str(page)]).exit_code in (0, 1)
    table = page.read_text().split("What changed")[1].split("</table>")[0]
    assert "nan" not in table and "<td>-</td>" in table
