"""A model path that is not a regular file is refused saying what it is, one line, exit 2, nothing recorded.

A folder and a link loop were both refused as "no such file", though the first existed.
"""

import os
import re

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

pytest.importorskip("onnxruntime")
pytest.importorskip("onnx")

from cli_util import one_error  # noqa: E402
from test_onnx_model_checks import HOME, constant_model  # noqa: E402

from cellguard.cli import app  # noqa: E402


def _run(tmp_path, model):
    scenario = tmp_path / "scenario.yaml"
    scenario.write_text(yaml.safe_dump({"cell": "arm-pick-place", "seed": 3, "acceptance_cycles": 1,
                                        "production_cycles": 0, "policy": f"onnx:{model}"}))
    return CliRunner().invoke(app, ["run", str(scenario), "--out", str(tmp_path / "out")])


def _folder(path):
    path.mkdir()


def _loop(path):
    path.symlink_to(path.name)


def _dangling(path):
    path.symlink_to("nowhere.onnx")


def _fifo(path):
    os.mkfifo(path)


@pytest.mark.parametrize("make, said", [
    (_folder, "is a folder, not a model file"),
    (_loop, r"cannot read the model file \(Too many levels of symbolic links\)"),
    (_dangling, "is a link to nothing"),
    (_fifo, "is a FIFO, not a model file"),
    (lambda path: None, "no such file"),
])
def test_a_model_path_that_is_no_regular_file_says_what_it_is(tmp_path, make, said):
    model = tmp_path / "m.onnx"
    make(model)
    line = one_error(_run(tmp_path, model))
    assert re.fullmatch(rf"error: policy: onnx:{re.escape(str(model))}: {said}", line), line
    assert not (tmp_path / "out").exists()


def test_a_link_to_a_model_file_loads(tmp_path):
    model = constant_model(tmp_path / "real.onnx", np.tile(HOME, (10, 1)).astype(np.float32)[None], [1, 10, 6])
    (tmp_path / "m.onnx").symlink_to(model.name)
    result = _run(tmp_path, tmp_path / "m.onnx")
    assert result.exit_code == 0, result.output
