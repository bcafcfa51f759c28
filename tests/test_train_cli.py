"""``cellguard train-demo-policy``: its ONNX file never replaces a record, a run folder's file or an existing
model (unless --overwrite), the output is checked before the demonstrations are recorded, and the path is
printed as given."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

from cellguard.calibrate.excitation import excitation_scenario, excite
from cellguard.cli import app
from cellguard.policy.onnx_export import save_mlp_onnx, trajectory_mlp

runner = CliRunner()
QUICK = ["--cycles", "2", "--random-features", "0"]


@pytest.fixture(scope="module")
def excited(tmp_path_factory):
    out = tmp_path_factory.mktemp("train") / "ex"
    excite(excitation_scenario("arm-pick-place", 1.0), out)
    return out


def test_a_refused_output_is_refused_before_any_training(excited, tmp_path):
    """500 demonstration cycles take minutes: refused at once, the check came first (it came after them)."""
    record = excited / "record.mcap"
    before = record.read_bytes()
    (tmp_path / "released.onnx").write_bytes(b"a model a release hashed")
    for target, says in ((record, "in the run folder"), (excited / "demo.onnx", "in the run folder"),
                         (tmp_path / "released.onnx", "already exists; choose another path or give --overwrite")):
        done = subprocess.run([sys.executable, "-c", "from cellguard.cli import app; app()", "train-demo-policy",
                               "--cycles", "500", "-o", str(target)], capture_output=True, text=True, timeout=60)
        assert done.returncode == 2 and done.stdout == "", done.stderr
        assert done.stderr.startswith(f"error: -o {target}: ") and says in done.stderr and done.stderr.count("\n") == 1
    assert record.read_bytes() == before and not (excited / "demo.onnx").exists()
    assert (tmp_path / "released.onnx").read_bytes() == b"a model a release hashed"


def test_overwrite_replaces_a_model_and_the_path_prints_as_given(tmp_path):
    out = tmp_path / "[bold]demo[red]\x1b[2J.onnx"
    old = save_mlp_onnx(trajectory_mlp(np.array([0.0, 1.0]), np.zeros((2, 6)), 2, 0.05), out, {}).read_bytes()
    result = runner.invoke(app, ["train-demo-policy", *QUICK, "-o", str(out), "--overwrite"])
    assert result.exit_code == 0, result.output
    assert out.read_bytes() != old and len(out.read_bytes()) > 1000
    shown = str(out).replace("\x1b", "\\x1b")
    assert f"written to {shown}; run it with policy: onnx:{shown}\n" in result.stdout


def test_a_file_that_appears_at_the_output_during_training_is_kept(tmp_path, monkeypatch):
    """The check before the training does not hold at its end: a file written meanwhile was replaced."""
    from cellguard.train import demo_policy

    out, fit = tmp_path / "model.onnx", demo_policy.fit_network

    def fit_while_someone_writes(*args, **kwargs):
        out.write_bytes(b"written during the training")
        return fit(*args, **kwargs)

    monkeypatch.setattr(demo_policy, "fit_network", fit_while_someone_writes)
    result = runner.invoke(app, ["train-demo-policy", *QUICK, "-o", str(out)])
    assert result.exit_code == 2 and result.stdout == ""
    assert result.stderr == f"error: ONNX model {out}: something was put there while it was being made; it is kept " \
                            "(nothing written)\n"
    assert out.read_bytes() == b"written during the training" and [p.name for p in tmp_path.iterdir()] == [out.name]


def test_help_keeps_the_unit():
    result = runner.invoke(app, ["train-demo-policy", "--help"], env={"COLUMNS": "200"})
    assert "moved this far in x [mm]" in result.output
