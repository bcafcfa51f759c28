"""An acceptance that was not steady, a closed pipe, a record with no cycles: what diagnose says."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.cli.diagnose import print_diagnosis
from cellguard.diagnose import Baseline, as_cycles, diagnose
from cellguard.report.html import render_report
from record_synth import record

ENV = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}


def _rows(ramp: float) -> list[dict]:
    """10 acceptance and 30 production cycles; the elbow's current grows by ``ramp`` of itself a cycle
    from cycle 0 on (a fault already under way at acceptance)."""
    rng = np.random.default_rng(3)
    out = []
    for c in range(40):
        f = {"current_rms.elbow": 0.4 * (1 + ramp * c) + 0.001 * rng.standard_normal(),
             "tracking_rms.elbow": 0.0133 + 1e-5 * rng.standard_normal(), "grasped": 1.0}
        out.append({"cycle": c, "phase": "acceptance" if c < 10 else "production", "success": True, "features": f})
    return out


def test_a_trend_in_acceptance_is_kept_with_the_baseline_and_told_in_the_finding(tmp_path):
    d = diagnose(_rows(0.007), [], {})
    assert set(d.baseline.trends) == {"current_rms.elbow"}
    assert 0.02 < d.baseline.trends["current_rms.elbow"] / 0.4 < 0.09  # about 9 x 0.7 % over cycles 0 to 9
    assert any("acceptance cycles were not steady" in e for f in d.findings for e in f.evidence)
    assert d.to_dict()["baseline_trends"] == {"current_rms.elbow": d.baseline.trends["current_rms.elbow"]}
    d.baseline.save(tmp_path / "baseline.json")
    assert Baseline.load(tmp_path / "baseline.json").trends == d.baseline.trends


def test_a_steady_acceptance_has_no_trend():
    assert Baseline.from_cycles(as_cycles(_rows(0.0)[:10])).trends == {}


def test_diagnose_warns_of_an_unsteady_acceptance_and_exits_1(tmp_path):
    record(tmp_path / "run", 20, 3)  # current_peak.elbow is the cycle's index: it climbs through acceptance
    result = CliRunner().invoke(app, ["diagnose", str(tmp_path / "run")])
    assert result.exit_code == 1, result.output
    assert "warning: baseline: the acceptance cycles were not steady (current_peak.elbow" in result.output


def test_diagnose_into_a_closed_pipe_exits_141_quietly(tmp_path):
    record(tmp_path / "run", 20, 3)
    for extra in ([], ["--json"]):
        p = subprocess.Popen([sys.executable, "-c", "from cellguard.cli import app; app()", "diagnose", str(tmp_path / "run"), *extra],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=ENV)
        p.stdout.close()  # as `| head -1` does once it has its line
        err = p.stderr.read().decode()
        assert p.wait() == 141 and "Traceback" not in err, err


def test_a_record_without_cycles_is_named(tmp_path):
    record(tmp_path / "run", 0, 3)
    result = CliRunner().invoke(app, ["diagnose", str(tmp_path / "run")])
    assert result.exit_code == 2
    assert f"{tmp_path / 'run'}: baseline: needs at least 5 acceptance cycles, got 0" in result.output


def test_cycles_that_carried_no_part_are_named_as_unwatched_for_joint_faults(capsys):
    """A camera fault (no part grasped from cycle 25) blinded every joint monitor, and a servo fault beside it
    vanished without a word: the cycles whose load-dependent features go unwatched are named."""
    rows = _rows(0.0)
    for r in rows[25:]:
        r["features"]["grasped"] = 0.0
    d = diagnose(rows, [], {})
    assert d.unwatched == tuple(range(25, 40)) and d.to_dict()["load_features_unwatched_cycles"] == list(range(25, 40))
    assert diagnose(_rows(0.0), [], {}).unwatched == ()
    print_diagnosis(d)
    said = " ".join(capsys.readouterr().out.split())
    assert "unwatched on 15 production cycle(s)" in said and "(cycles 25, 26, 27, 28, 29, 30, 31, 32 ...)" in said
    assert "class=ok>joint currents and tracking unwatched on 15" in render_report(d)


def test_a_baseline_json_an_earlier_version_took_from_this_record_is_taken_again(tmp_path):
    """A run folder diagnosed before the small-sample bound kept its winsorised scales (too low: a healthy arm
    named part_misplaced) in baseline.json, and every later diagnosis reused them."""
    import json

    record(tmp_path / "run", 20, 3)
    assert CliRunner().invoke(app, ["diagnose", str(tmp_path / "run")]).exit_code in (0, 1)
    path = tmp_path / "run" / "baseline.json"
    fresh = json.loads(path.read_text())
    assert fresh["method"] == 2
    old = json.loads(path.read_text())
    del old["method"]  # as the version before wrote it
    for stats in old["motions"].values():
        for feature in stats["features"].values():
            feature["scale"] /= 3
    path.write_text(json.dumps(old))
    assert CliRunner().invoke(app, ["diagnose", str(tmp_path / "run")]).exit_code in (0, 1)
    assert json.loads(path.read_text()) == fresh
    stored = {**fresh, "source": "acceptance cycles of another record", "method": 1}
    path.write_text(json.dumps(stored))  # one a person put there on purpose is kept as it is
    CliRunner().invoke(app, ["diagnose", str(tmp_path / "run")])
    assert json.loads(path.read_text()) == stored
