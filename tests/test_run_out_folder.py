"""``run`` and ``demo --out``: the folder is printed as given, a folder holding anything a run writes or lying
inside a run folder is refused before anything runs, and a disk without room for the summary's reserve runs
nothing; ``bench`` on a full TMPDIR is one line too."""

from __future__ import annotations

import errno
import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from cli_util import one_error
from run_copies import small_tmpfs
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.record.writer import RECORD_FILE, RUN_OUTPUTS

runner = CliRunner()


def scenario(folder: Path, acceptance: int = 0, production: int = 1) -> Path:
    path = folder / f"s{acceptance}_{production}.yaml"
    path.write_text(yaml.safe_dump({"cell": "arm-pick-place", "seed": 1, "acceptance_cycles": acceptance,
                                    "production_cycles": production}))
    return path


def digests(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A run folder (record, index, summary) and the scenario that made it."""
    root = tmp_path_factory.mktemp("runs")
    path = scenario(root)
    result = runner.invoke(app, ["run", str(path), "--out", str(root / "run"), "--json"])
    assert result.exit_code == 0, result.output
    return root / "run", path


def no_space(*args):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


# -- 2: paths printed as given -----------------------------------------------------------------------
@pytest.mark.parametrize("name", ["a[/]b", "[red]x", "e\x1b[31mx"])
def test_run_prints_its_out_folder_as_given(recorded, tmp_path, name):
    out = tmp_path / "runs" / name
    result = runner.invoke(app, ["run", str(recorded[1]), "--out", str(out)])
    assert result.exit_code == 0, result.output
    shown = str(out).replace("\x1b", "\\x1b")  # the escape code written out, never sent to the terminal
    assert result.stdout.splitlines()[-1] == f"events: 0; written to {shown}"
    assert (out / RECORD_FILE).is_file() and (out / "summary.json").is_file()
    assert "arm-pick-place [production]" in result.stderr  # the progress line keeps its phase too


def test_demo_prints_its_out_folder_and_report_as_given(tmp_path, monkeypatch):
    from cellguard.cli import run as run_cli

    monkeypatch.setattr(run_cli, "DEMO_SCENARIO", scenario(tmp_path, acceptance=5, production=1))  # a short demo
    out = tmp_path / "dm[/]x"
    result = runner.invoke(app, ["demo", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert f"events: 0; written to {out}" in result.stdout.splitlines()
    assert result.stdout.splitlines()[-1] == f"report: {out / 'report.html'}"
    assert "<html" in (out / "report.html").read_text()


def test_demo_runs_again_into_its_folder_with_overwrite(tmp_path, monkeypatch):
    """The README's second run: the old baseline.json, bound to the replaced record, stayed and the new run's
    diagnosis refused it (exit 2 after the whole shift had run)."""
    from cellguard.cli import run as run_cli

    monkeypatch.setattr(run_cli, "DEMO_SCENARIO", scenario(tmp_path, acceptance=5, production=1))  # a short demo
    out = tmp_path / "demo"
    assert runner.invoke(app, ["demo", "--out", str(out)]).exit_code == 0
    first = json.loads((out / "baseline.json").read_text())["bound_to"]["record_id"]
    result = runner.invoke(app, ["demo", "--out", str(out), "--overwrite"])
    assert result.exit_code == 0, result.output
    assert json.loads((out / "baseline.json").read_text())["bound_to"]["record_id"] != first


# -- 6: nothing a run writes is overwritten without --overwrite --------------------------------------
def test_the_names_a_run_writes_are_those_of_the_layers_that_write_them():
    from cellguard.diagnose.from_record import BASELINE_FILE
    from cellguard.diagnose.site_history import FIXES_FILE
    from cellguard.release.evidence import SHADOW_FILE
    from cellguard.report.from_record import REPORT_FILE

    assert set(RUN_OUTPUTS) == {"summary.json", BASELINE_FILE, FIXES_FILE, REPORT_FILE, SHADOW_FILE}


@pytest.mark.parametrize("name", [*RUN_OUTPUTS, "index/cycles/day=2026-01-01/part-00000000.parquet"])
def test_a_folder_holding_what_a_run_writes_is_refused_without_overwrite(recorded, tmp_path, name):
    out = tmp_path / "o"
    mine = out / name
    mine.parent.mkdir(parents=True)
    mine.write_text('{"mine": 1}')
    before = digests(out)
    line = one_error(runner.invoke(app, ["run", str(recorded[1]), "--out", str(out)]))
    assert line.startswith(f"error: --out {out}: already holds {name.split('/')[0]}") and "--overwrite" in line
    assert digests(out) == before and not (out / ".cellguard-reserve").exists()
    result = runner.invoke(app, ["run", str(recorded[1]), "--out", str(out), "--overwrite", "--json"])
    assert result.exit_code == 0, result.output  # asked for: the run goes ahead
    assert (out / RECORD_FILE).is_file()


def test_a_fifo_named_summary_json_is_refused_before_anything_runs(recorded, tmp_path):
    out = tmp_path / "o"
    out.mkdir()
    os.mkfifo(out / "summary.json")
    line = one_error(runner.invoke(app, ["run", str(recorded[1]), "--out", str(out)]))
    assert "already holds summary.json" in line
    assert (out / "summary.json").is_fifo() and sorted(os.listdir(out)) == ["summary.json"]


# -- 7: never inside a run folder ---------------------------------------------------------------------
@pytest.mark.parametrize("command", ["run", "demo"])
@pytest.mark.parametrize("inside", ["index", "sub", "sub/deeper", RECORD_FILE, "LINK/sub"])
def test_an_out_folder_inside_a_run_folder_is_refused(recorded, tmp_path, command, inside):
    run, path = recorded
    (tmp_path / "link").symlink_to(run)
    out = tmp_path / "link" / "sub" if inside == "LINK/sub" else run / inside
    before = digests(run)
    args = ["run", str(path)] if command == "run" else ["demo"]
    for overwrite in ([], ["--overwrite"]):  # --overwrite replaces a record in --out, never writes into another's
        line = one_error(runner.invoke(app, [*args, "--out", str(out), *overwrite]))
        assert line.startswith(f"error: --out {out}: is in the run folder {run.resolve()}, which holds a record")
    assert digests(run) == before
    assert not (run / "sub").exists() and (run / RECORD_FILE).is_file()


def test_the_recorder_refuses_a_folder_inside_a_run_folder(recorded):
    from record_synth import DT_NS, JOINTS, context

    from cellguard.errors import RecordError
    from cellguard.record.writer import Recorder

    run, _ = recorded
    with pytest.raises(RecordError, match="is in the run folder"):
        Recorder.create(run / "nested", joints=JOINTS, dt_ns=DT_NS, context=context())
    assert not (run / "nested").exists()


# -- 5: no room for the summary's reserve: nothing runs ----------------------------------------------
def test_no_room_for_the_reserve_runs_nothing_and_leaves_nothing(recorded, tmp_path, monkeypatch):
    monkeypatch.setattr(os, "posix_fallocate", no_space)
    out = tmp_path / "full" / "run"
    line = one_error(runner.invoke(app, ["run", str(recorded[1]), "--out", str(out)]))
    assert "cannot start the record" in line and "summary.json" in line and "No space left" in line
    assert not out.exists()  # no record, no reserve, no empty folder


def test_the_reserve_is_refused_in_the_recording_itself(tmp_path, monkeypatch):
    from cellguard.errors import RecordError
    from cellguard.record.session import RunRecording
    from cellguard.runtime import Run
    from cellguard.scenario import parse_scenario

    run = Run(parse_scenario({"cell": "arm-pick-place", "seed": 1, "acceptance_cycles": 0, "production_cycles": 1}))
    monkeypatch.setattr(os, "posix_fallocate", no_space)
    try:
        with pytest.raises(RecordError, match="cannot start the record"):
            run.recording = RunRecording.start(tmp_path, run)
    finally:
        run.close()
    assert list(tmp_path.iterdir()) == []


def test_a_filesystem_without_fallocate_still_gets_its_reserve(tmp_path, monkeypatch):
    from cellguard.record.session import RESERVE_BYTES, RESERVE_FILE, RunRecording
    from cellguard.runtime import Run
    from cellguard.scenario import parse_scenario

    def unsupported(*args):
        raise OSError(errno.EOPNOTSUPP, os.strerror(errno.EOPNOTSUPP))

    run = Run(parse_scenario({"cell": "arm-pick-place", "seed": 1, "acceptance_cycles": 0, "production_cycles": 1}))
    monkeypatch.setattr(os, "posix_fallocate", unsupported)
    try:
        run.recording = RunRecording.start(tmp_path, run)
        assert (tmp_path / RESERVE_FILE).stat().st_size == RESERVE_BYTES[0] + RESERVE_BYTES[1]
        run.recording.close()
    finally:
        run.close()
    assert not (tmp_path / RESERVE_FILE).exists()


def test_a_disk_too_small_for_the_reserve_runs_nothing(recorded, tmp_path):
    """On a real 64 KiB tmpfs: the run went ahead without a reserve, filled the disk, and ended with a record and
    no summary (exit 2, partial)."""
    with small_tmpfs(tmp_path / "disk", "64k") as disk:
        result = subprocess.run([sys.executable, "-c", "from cellguard.cli import app; app()", "run",
                                 str(recorded[1]), "--out", str(disk / "run")], capture_output=True, text=True,
                                timeout=600)
        listing = os.listdir(disk)
    assert result.returncode == 2 and "Traceback" not in result.stderr
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and "cannot start the record" in lines[0] and "summary.json" in lines[0], result.stderr
    assert listing == []


# -- 3: bench on a full TMPDIR -------------------------------------------------------------------------
def test_bench_on_a_full_disk_is_one_line(monkeypatch):
    monkeypatch.setattr(os, "posix_fallocate", no_space)
    line = one_error(runner.invoke(app, ["bench", "--only", "record", "--quick", "--json"]))
    assert line.startswith("error: benchmark record: ") and "cannot start the record" in line


def test_bench_names_a_temporary_file_it_cannot_write(monkeypatch):
    from cellguard.cli import bench

    def full(quick):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), "/tmp/x/index/part-0.parquet")

    monkeypatch.setitem(bench.BENCHMARKS, "record", full)
    line = one_error(runner.invoke(app, ["bench", "--only", "record", "--json"]))
    assert line == "error: benchmark record: /tmp/x/index/part-0.parquet: No space left on device"
