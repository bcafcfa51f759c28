"""A run folder another run is still writing: ``run --overwrite`` into it destroyed both records (the live file
truncated in place under its writer) and both runs ended 0. The writing run holds a lock on its folder for its
whole life (``record.folder_lock``), shared with its writer process; ``--overwrite`` is refused while it is held,
and a replaced record is unlinked, never truncated."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import RecordError
from cellguard.record import folder_lock
from cellguard.record.session import RunRecording
from cellguard.record.writer import RECORD_FILE
from cellguard.runtime import Run
from cellguard.scenario import load_scenario

runner = CliRunner()


def _scenario(folder: Path) -> Path:
    path = folder / "s.yaml"
    path.write_text(yaml.safe_dump({"cell": "arm-pick-place", "seed": 1, "acceptance_cycles": 0,
                                    "production_cycles": 1}))
    return path


def _digests(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture
def finished(tmp_path):
    """A finished run folder and its scenario."""
    path = _scenario(tmp_path)
    assert runner.invoke(app, ["run", str(path), "--out", str(tmp_path / "run")]).exit_code == 0
    return tmp_path / "run", path


def test_overwrite_into_a_folder_a_run_is_writing_is_refused_and_touches_nothing(finished):
    out, path = finished
    before = _digests(out)
    lock = folder_lock.hold(out)  # as the live run's recording holds it
    try:
        result = runner.invoke(app, ["run", str(path), "--out", str(out), "--overwrite"])
    finally:
        folder_lock.release(lock)
    assert result.exit_code == 2, result.output
    assert result.stderr == (f"error: --out {out}: another run is still writing its record there (pid "
                             f"{os.getpid()}); nothing was touched: wait for it to end or choose another folder\n")
    assert _digests(out) == before


def test_a_recording_holds_its_folder_until_its_writer_has_finished(tmp_path, finished):
    _, path = finished
    run = Run(load_scenario(path))
    run.recording = RunRecording.start(tmp_path / "live", run)
    try:
        with pytest.raises(RecordError, match="another run is still writing"):
            folder_lock.hold(tmp_path / "live")
        run.cycle()
    finally:
        run.recording.close()
        run.close()
    folder_lock.release(folder_lock.hold(tmp_path / "live"))  # let go at close


def test_overwrite_unlinks_the_old_record_and_never_truncates_it(finished, tmp_path):
    """A hard link (or a reader holding it open) keeps the replaced record's bytes."""
    out, path = finished
    kept = tmp_path / "kept.mcap"
    os.link(out / RECORD_FILE, kept)
    old = hashlib.sha256(kept.read_bytes()).hexdigest()
    assert runner.invoke(app, ["run", str(path), "--out", str(out), "--overwrite"]).exit_code == 0
    assert hashlib.sha256(kept.read_bytes()).hexdigest() == old
    assert not os.path.samefile(kept, out / RECORD_FILE)
