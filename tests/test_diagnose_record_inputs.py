"""What `cellguard diagnose` and `report` take as a baseline and as a record: a baseline that would blind
the diagnosis (another robot's, another cell's, unbound, malformed) is refused with one line, never
applied; a run folder's record.mcap is read like its folder (real records from `cellguard run`)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.diagnose import Baseline
from cellguard.errors import RecordError

runner = CliRunner()


def _run(root: Path, scenario: dict) -> Path:
    (root / "scenario.yaml").write_text(yaml.safe_dump(scenario))
    out = root / "out"
    result = runner.invoke(app, ["run", str(root / "scenario.yaml"), "--out", str(out), "--json"])
    assert result.exit_code == 0, result.output
    result = runner.invoke(app, ["diagnose", str(out), "--no-fleet", "--json"])  # writes its baseline.json
    assert result.exit_code == 0, result.output
    return out


@pytest.fixture(scope="module")
def arm(tmp_path_factory) -> Path:
    return _run(tmp_path_factory.mktemp("arm"), {
        "cell": "arm-pick-place", "seed": 3, "acceptance_cycles": 6, "production_cycles": 4,
        "faults": [{"kind": "fixture_shift", "at_cycle": 7, "dx_mm": 4.0}]})


@pytest.fixture(scope="module")
def quad(tmp_path_factory) -> Path:
    return _run(tmp_path_factory.mktemp("quad"), {"cell": "quadruped-turns", "seed": 3, "acceptance_cycles": 10,
                                                  "production_cycles": 2})


def _stored(run: Path) -> dict:
    return json.loads((run / "baseline.json").read_text())


def _folder(tmp_path: Path, run: Path, baseline: dict | None = None, name: str = "run") -> Path:
    """A run folder holding a copy of ``run``'s record and, if given, ``baseline`` as its baseline.json."""
    folder = tmp_path / name
    folder.mkdir()
    (folder / "record.mcap").write_bytes((run / "record.mcap").read_bytes())
    if baseline is not None:
        (folder / "baseline.json").write_text(json.dumps(baseline))
    return folder


def _diagnose(*args) -> tuple[int, str]:
    result = runner.invoke(app, ["diagnose", *map(str, args), "--no-fleet", "--json"])
    return result.exit_code, result.output


def _one_error(code: int, output: str) -> str:
    assert code == 2, output
    assert output.startswith("error:") and output.strip().count("\n") == 0, output
    return output


def test_an_acceptance_record_of_another_robot_is_refused(arm, quad, tmp_path):
    folder = _folder(tmp_path, arm)
    for command in ("diagnose", "report"):
        result = runner.invoke(app, [command, str(folder), "--acceptance", str(quad), "--no-fleet"])
        assert "is a record of robot 'quadruped-turns'" in _one_error(result.exit_code, result.output)
    assert not (folder / "report.html").exists() and not (folder / "baseline.json").exists()
    assert "is a record of robot 'arm-pick-place'" in _one_error(*_diagnose(_folder(tmp_path, quad, name="q"),
                                                                           "--acceptance", arm))
    code, out = _diagnose(folder, "--acceptance", arm)  # a record of the same robot is the baseline
    assert code == 0, out
    assert json.loads(out)["findings"][0]["cause"] == "fixture_shift"


def test_a_stored_baseline_that_does_not_name_its_record_is_refused_and_kept(arm, quad, tmp_path):
    own = {k: v for k, v in _stored(arm).items() if k != "bound_to"}
    foreign = {k: v for k, v in _stored(quad).items() if k != "bound_to"}
    for name, baseline in (("own", own), ("foreign", foreign)):
        folder = _folder(tmp_path, arm, baseline, name)
        before = (folder / "baseline.json").read_bytes()
        for target in (folder, folder / "record.mcap"):  # the record file is read with its folder's baseline
            assert "baseline does not name the robot" in _one_error(*_diagnose(target))
        assert (folder / "baseline.json").read_bytes() == before


def test_a_stored_baseline_of_another_cell_is_refused_though_bound_to_this_record(arm, quad, tmp_path):
    forged = {**_stored(quad), "bound_to": _stored(arm)["bound_to"]}
    assert "baseline is of another cell" in _one_error(*_diagnose(_folder(tmp_path, arm, forged)))


def test_a_stored_baseline_without_statistics_for_the_records_motions_is_refused(arm, quad, tmp_path):
    renamed = _stored(arm)
    renamed["motions"] = {"x": renamed["motions"][""]}
    assert "no statistics for motion ''" in _one_error(*_diagnose(_folder(tmp_path, arm, renamed, "arm")))
    left_only = _stored(quad)
    left_only["motions"] = {"left": left_only["motions"]["left"]}
    left_only["n"] = left_only["motions"]["left"]["n"]
    assert "no statistics for motion 'right'" in _one_error(*_diagnose(_folder(tmp_path, quad, left_only, "quad")))


def _nan_medians(b):
    for m in b["motions"].values():
        for f in m["features"].values():
            f["median"] = math.nan


def _one_name_twice(b):
    b["names"] = b["names"][:1] * 2
    for m in b["motions"].values():
        m["correlation"] = [[1.0, 0.0], [0.0, 1.0]]


def _no_names(b):
    b["names"] = []
    for m in b["motions"].values():
        m["correlation"] = []


def _nan_correlation(b):
    for m in b["motions"].values():
        m["correlation"] = [[math.nan] * len(r) for r in m["correlation"]]


MALFORMED = {  # the edit, and the field the message must name (a regular expression)
    "medians NaN": (_nan_medians, r"motions\.\(all\)\.features\.\w+\.median"),
    "load text": (lambda b: b.update(load="heavy"), "load"),
    "load NaN": (lambda b: b.update(load=math.nan), "load"),
    "a name twice": (_one_name_twice, "names"),
    "no names": (_no_names, "names"),
    "a name not text": (lambda b: b.update(names=[1, *b["names"][1:]]), r"names\[0\]"),
    "correlation NaN": (_nan_correlation, r"motions\.\(all\)\.correlation"),
    "n negative": (lambda b: b.update(n=-5), "n"),
    "cycles text": (lambda b: b.update(cycles="ab"), "cycles"),
    "a motion's n zero": (lambda b: b["motions"][""].update(n=0), r"motions\.\(all\)\.n"),
}


@pytest.mark.parametrize("case", list(MALFORMED))
def test_a_malformed_baseline_is_refused_naming_the_field(arm, tmp_path, case):
    edit, field = MALFORMED[case]
    baseline = _stored(arm)
    edit(baseline)
    (tmp_path / "baseline.json").write_text(json.dumps(baseline))
    with pytest.raises(RecordError, match=rf"baseline: malformed: {field} ") as exc:
        Baseline.load(tmp_path / "baseline.json")
    assert "\n" not in str(exc.value)


@pytest.mark.parametrize("case", ["medians NaN", "no names"])
def test_a_malformed_stored_baseline_stops_the_diagnosis_with_one_line(arm, tmp_path, case):
    baseline = _stored(arm)
    MALFORMED[case][0](baseline)
    assert "baseline: malformed" in _one_error(*_diagnose(_folder(tmp_path, arm, baseline)))


def test_report_of_a_run_folders_record_file_writes_the_folders_report(arm, tmp_path):
    folder = _folder(tmp_path, arm, _stored(arm))
    result = runner.invoke(app, ["report", str(folder / "record.mcap"), "--no-fleet"])
    assert result.exit_code == 0, result.output
    assert "fixture_shift" in (folder / "report.html").read_text()
    loose = tmp_path / "loose.mcap"  # a record file outside any run folder: nowhere to put report.html
    loose.write_bytes((arm / "record.mcap").read_bytes())
    result = runner.invoke(app, ["report", str(loose), "--no-fleet"])
    assert "outside a run folder; name the page to write with -o FILE" in _one_error(result.exit_code, result.output)
    result = runner.invoke(app, ["report", str(loose), "-o", str(tmp_path / "page.html"), "--no-fleet"])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "page.html").is_file() and sorted(p.name for p in tmp_path.iterdir()) == [
        "loose.mcap", "page.html", "run"]


def test_an_acceptance_record_gives_the_baseline_its_own_diagnosis_gives(tmp_path):
    """Acceptance cycles a recovery drove keep only their grasp geometry in the record's own baseline; taken
    through --acceptance they were used whole, so the same record gave another baseline."""
    from cellguard.diagnose.from_record import diagnose_record

    run = _run(tmp_path, {"cell": "arm-pick-place", "seed": 3, "acceptance_cycles": 8, "production_cycles": 2,
                          "faults": [{"kind": "intermittent_slip", "rate": 0.3, "dx_mm": -5.0}],
                          "recovery": {"behaviours": [{"do": "retry_grasp", "trigger": "grasp_missed",
                                                       "attempts": 2}]}})
    own = Baseline.load(run / "baseline.json")
    assert own.n == 8  # the acceptance cycles, some of which a recovery drove (the slip is random, seeded)
    summary = json.loads((run / "summary.json").read_text())
    assert any(c.get("recoveries") for c in summary["cycles"][:8])
    taken = diagnose_record(_folder(tmp_path, run), acceptance=run).baseline
    for label, stats in own.motions.items():
        assert taken.motions[label].median == stats.median and taken.motions[label].scale == stats.scale
