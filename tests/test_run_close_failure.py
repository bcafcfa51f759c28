"""``cellguard run`` when the record cannot be finished at its close: the summary or the index of the file could
not be written (a file size limit just past the last chunk, an immutable index folder). The run ended 0 with its
usual summary; now one line saying what is whole, and exit 1, as for a write error mid-run."""

from __future__ import annotations

import errno
import json
import os

import pytest
import yaml
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import OutputError
from cellguard.record import index, writer

runner = CliRunner()


@pytest.fixture
def short(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump({"cell": "arm-pick-place", "seed": 1, "acceptance_cycles": 0,
                                    "production_cycles": 1}))
    return path


def _denied(*args, **kwargs):
    raise OSError(errno.EPERM, os.strerror(errno.EPERM))


def _error_line(result) -> str:
    errors = [line for line in result.stderr.splitlines() if line.startswith("error")]
    assert len(errors) == 1 and "Traceback" not in result.output, result.stderr
    assert result.stderr.rstrip("\n").splitlines()[-1] == errors[0], result.stderr  # the last word
    return errors[0]


def test_an_index_that_cannot_be_written_at_close_is_one_line_and_exit_1(short, tmp_path, monkeypatch):
    monkeypatch.setattr(index.IndexWriter, "flush", _denied)  # the writer process is forked: it inherits this
    out = tmp_path / "out"
    result = runner.invoke(app, ["run", str(short), "--out", str(out)])
    assert result.exit_code == 1, result.output
    line = _error_line(result)
    assert line.startswith(f"error: the record in {out} failed at its close: {out / 'index'}: cannot write the index")
    assert "record.mcap is finished and whole" in line and "record recover" in line
    assert "cannot write the index" in json.loads((out / "summary.json").read_text())["record_failed"]
    assert runner.invoke(app, ["record", "info", str(out)]).exit_code == 0  # the file itself is whole


def test_a_record_whose_summary_cannot_be_written_at_close_is_one_line_and_exit_1(short, tmp_path, monkeypatch):
    monkeypatch.setattr(writer.Writer, "finish", lambda self: _denied())
    out = tmp_path / "out"
    result = runner.invoke(app, ["run", str(short), "--out", str(out), "--json"])
    assert result.exit_code == 1, result.output
    line = _error_line(result)
    assert line.startswith(f"error: the record in {out} failed at its close: {out / 'record.mcap'}: cannot write "
                           f"the record (EPERM")


def test_a_finished_record_without_its_summary_is_not_called_partial(short, tmp_path, monkeypatch):
    """The run folder made immutable after the record closed: the record is whole, only summary.json is missing;
    the line said `partial` and the exit was 2 (nothing done)."""
    from cellguard.runtime import loop

    def no_summary(path, *args, **kwargs):
        raise OutputError(f"summary {path}: cannot write (Operation not permitted)")

    monkeypatch.setattr(loop, "write_output", no_summary)
    out = tmp_path / "out"
    result = runner.invoke(app, ["run", str(short), "--out", str(out)])
    assert result.exit_code == 1, result.output
    line = _error_line(result)
    assert line == (f"error: summary {out / 'summary.json'}: cannot write (Operation not permitted); the record in "
                    f"{out} is finished and whole; it has no summary.json")
    assert runner.invoke(app, ["record", "info", str(out)]).exit_code == 0


def test_an_excitation_whose_index_cannot_be_written_at_close_is_one_line_and_exit_1(tmp_path, monkeypatch):
    """`excite` ended 0 with its usual line, and `identify` then read a record without its index."""
    monkeypatch.setattr(index.IndexWriter, "flush", _denied)
    out = tmp_path / "excite"
    result = runner.invoke(app, ["excite", "arm-pick-place", "--seconds", "7", "--out", str(out)])
    assert result.exit_code == 1, result.output
    assert _error_line(result).startswith(f"error: the record in {out} failed at its close: {out / 'index'}")
